"""A hysteresis loop that closes inside the data: `fit` and `refine` call such an estimate a
success only where its own covariance pins the loop's free run (``RESULTS.loop_unresolved``
otherwise, ``hbjax/_identify/loop.py``); an extrapolated branch of the paper's class that
crosses outside the inputs where both branches act is not judged. Systems and records come
from the independent generator (``tests/generators/paper_class.py``)."""

import jax
import numpy as np
import pytest

import hbjax
from tests.generators.paper_class import (
    random_closing_loop_system,
    random_input,
    simulate_numpy,
    to_hbjax,
)
from tests.generators.paper_runs import reproduce


def _closing_record(rng, *, T, noise):
    """A random crossing system (na = nb = 2 after padding, m = 3: one compiled shape), a
    filtered-noise input of `T` samples and its output with equation noise `noise` x the
    noise-free output's range; and a fresh validation input of the same kind."""
    sys = random_closing_loop_system(rng, n=2, m=3, kind="cross")
    v = random_input(rng, "filtered_noise", T, sys["scale"])
    free, _ = simulate_numpy(sys, v)
    y, _ = simulate_numpy(sys, v, noise * float(np.ptp(free)) * rng.normal(size=T))
    return sys, v, y, random_input(rng, "filtered_noise", 2000, sys["scale"])


def _validation_fit(sys, model, v):
    truth, _ = simulate_numpy(sys, v)
    est = np.asarray(hbjax.simulate(model, v))
    return 100.0 * (1.0 - np.linalg.norm(truth - est) / np.linalg.norm(truth - truth.mean()))


def _spread(result, v):
    """The free-run fit shortfall (%) the result's own covariance predicts on `v`, from the
    public ``free_run_std`` (written here, not taken from the package's judgement)."""
    y = np.asarray(hbjax.simulate(result.model, v))
    std = np.asarray(result.free_run_std(v))
    return 100.0 * np.sqrt(np.sum(std**2)) / np.linalg.norm(y - y.mean())


@pytest.mark.slow
def test_a_closing_loop_is_a_success_only_where_the_records_pin_it():
    """Random crossing systems, short noisy records (T = 1500, 3 % noise) and long quiet
    ones (T = 6000, 0.2 %): every judged result is refused exactly when the spread its own
    covariance predicts exceeds 1 %; the short records are refused, and the long ones
    succeed with a validation fit of at least 99 % against the true system."""
    rng = np.random.default_rng(53)
    verdicts = {"short": [], "long": []}
    for kind, T, noise in (("short", 1500, 0.03), ("long", 6000, 0.002)) * 2:
        sys, v, y, v_val = _closing_record(rng, T=T, noise=noise)
        res = hbjax.fit([(v, y)], na=sys["na"], nb=len(sys["b"]), m=3,
                        key=jax.random.PRNGKey(T), throw=False, progress=False)
        judged = np.isfinite(float(res.loop_spread))
        if judged:
            assert float(res.loop_spread) == pytest.approx(_spread(res, v), rel=1e-6)
            refused = res.result == hbjax.RESULTS.loop_unresolved
            assert refused == (float(res.loop_spread) > 1.0), res.message
            if refused:
                assert f"{float(res.loop_spread):.3g} %" in res.message
                with pytest.raises(hbjax.RefinementError, match="loop"):
                    hbjax.fit([(v, y)], na=sys["na"], nb=len(sys["b"]), m=3,
                              key=jax.random.PRNGKey(T), progress=False)
        verdicts[kind].append((res.message, judged, _validation_fit(sys, res.model, v_val)))
    assert all(judged and not msg.startswith("success") for msg, judged, _ in verdicts["short"]), verdicts
    assert all(msg == "success" and fit >= 99.0 for msg, _, fit in verdicts["long"]), verdicts


@pytest.mark.slow
def test_refine_judges_the_loop_the_same_under_jit():
    """A refused closing loop: `refine(..., loop_tolerance=1.0)` eager and under `jax.jit`
    give the same code and spread (to 1 %: the eager call solves on records padded to a
    bucket and may leave a kink, the traced one does neither), and refine's default
    (``inf``) accepts the same model and reports the same spread."""
    rng = np.random.default_rng(54)
    sys, v, y, _ = _closing_record(rng, T=1500, noise=0.03)
    start = hbjax.normalise_static_gain(to_hbjax(sys))
    eager = hbjax.refine(start, [(v, y)], restarts=0, loop_tolerance=1.0, throw=False)
    assert eager.result == hbjax.RESULTS.loop_unresolved, eager.message
    traced = jax.jit(lambda vv, yy: hbjax.refine(start, [(vv, yy)], restarts=0,
                                                 loop_tolerance=1.0, throw=False))(v, y)
    assert traced.result == hbjax.RESULTS.loop_unresolved
    assert float(traced.loop_spread) == pytest.approx(float(eager.loop_spread), rel=1e-2)
    accepted = hbjax.refine(start, [(v, y)], restarts=0, throw=False)
    assert accepted.message == "success"
    assert float(accepted.loop_spread) == pytest.approx(float(eager.loop_spread), rel=1e-9)
    np.testing.assert_allclose(np.asarray(hbjax.flatten_params(accepted.model)),
                               np.asarray(hbjax.flatten_params(eager.model)), rtol=1e-9)


@pytest.mark.slow
def test_an_extrapolated_crossing_of_the_paper_class_is_not_judged():
    """Paper mode (seed 5, system 2, 5 % noise, draw 0 of the study): the refined branches
    cross where that decides outputs, but outside the inputs where both act; the free run
    of this slow system is uncertain far beyond 1 % (the noise integrated by 1/A), yet it
    is not a closing loop and stays a success."""
    sys, design, records, _ = reproduce(2, 0.05, 0, seed=5, levels=[0.01, 0.03, 0.05],
                                        draws=14, T=3000)
    (v1, y1), (v2, y2), (v3, y3) = records
    giri = hbjax.identify_giri(design, y1, y2, y3, v1=v1, v2=v2, v3=v3)
    res = hbjax.refine(giri.model, records, h_m=sys["h_m"], loop_tolerance=1.0)
    assert res.message == "success"
    assert bool(res.branches_cross)
    assert np.isnan(float(res.loop_spread))
    assert max(_spread(res, v) for v, _ in records) > 1.0


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "1", None])
def test_loop_tolerance_must_be_a_positive_number(bad):
    rng = np.random.default_rng(0)
    v = rng.normal(size=200)
    y = np.convolve(v, [0.0, 1.0])[:200]
    model = hbjax.Hammerstein(hbjax.Backlash([-0.1, 1.0], [0.1, 1.0]), hbjax.ARX([-0.5], [1.0]))
    with pytest.raises(ValueError, match="`loop_tolerance`"):
        hbjax.refine(model, [(v, y)], loop_tolerance=bad)
    with pytest.raises(ValueError, match="`loop_tolerance`"):
        hbjax.fit([(v, y)], na=1, nb=1, m=2, key=jax.random.PRNGKey(0), loop_tolerance=bad)


@pytest.mark.slow
def test_a_loop_that_touches_inside_the_data_is_judged_too():
    """Random *touching* systems (the branches meet at one input inside the range without
    crossing): a fit whose band comes within a rounding error of closing there, crossing or
    not, is judged like a closing loop: its spread is reported and it is refused exactly
    when that exceeds 1 %. Before this, a touching fit that did not cross was never judged,
    and two such successes of the closing-loop studies simulated validation inputs at 98.5
    and 98.0 % with spreads of 2.8 % (``benchmarks/RESULTS.md``)."""
    rng = np.random.default_rng(55)
    judged_open = 0
    for T in (1500, 3000, 1500, 3000, 1500, 3000):
        sys = random_closing_loop_system(rng, n=2, m=3, kind="touch")
        v = random_input(rng, "filtered_noise", T, sys["scale"])
        free, _ = simulate_numpy(sys, v)
        y, _ = simulate_numpy(sys, v, 0.01 * float(np.ptp(free)) * rng.normal(size=T))
        res = hbjax.fit([(v, y)], na=sys["na"], nb=len(sys["b"]), m=3,
                        key=jax.random.PRNGKey(T), throw=False, progress=False)
        if np.isfinite(float(res.loop_spread)):
            assert float(res.loop_spread) == pytest.approx(_spread(res, v), rel=1e-6)
            assert (res.result == hbjax.RESULTS.loop_unresolved) == (
                float(res.loop_spread) > 1.0), res.message
            judged_open += not bool(res.branches_cross)
    assert judged_open >= 1  # the rule reaches fits whose branches do not cross
