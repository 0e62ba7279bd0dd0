"""Mismatch diagnosis on data it was not tuned on: the independent concealed-effect
generator (tests/generators/concealed_effects.py) keeps its promises; on a small sample of
its cases the diagnosis holds its measured accuracy, and the accuracy target (a strict
xfail: it fails the suite once it passes, so that the marker is removed) is tracked."""

import collections
import inspect

import numpy as np
import pytest

import hbjax
from generators.concealed_effects import (
    ALL_EFFECTS, INPUT_KINDS, N_MAX, N_MIN, NOISE_MAX, NOISE_MIN, RATIO_MIN, arx,
    concealed_case, play, random_base, spread,
)


def _cases(effect, count, seed):
    rng = np.random.default_rng(seed)
    return [concealed_case(rng, effect, n=1000 + 500 * (i % 3)) for i in range(count)]


def _whiteness_z(x, lags=10):
    """Largest |autocorrelation| over lags 1..lags, in units of its null std 1/sqrt(T)."""
    x = x - x.mean()
    r = np.array([np.dot(x[:-k], x[k:]) for k in range(1, lags + 1)]) / np.dot(x, x)
    return float(np.max(np.abs(r)) * np.sqrt(len(x)))


def test_numpy_simulator_matches_hbjax():
    rng = np.random.default_rng(0)
    for _ in range(4):
        base = random_base(rng)
        v = rng.uniform(-base["amp"], base["amp"], 300).repeat(3)
        xi = 0.1 * rng.standard_normal(len(v))
        ours = arx(play(v, base["c1"], base["c2"]), xi, base["a"], base["b"])
        model = hbjax.Hammerstein(hbjax.Backlash(c1=base["c1"], c2=base["c2"]),
                                  hbjax.ARX(a=base["a"], b=base["b"]))
        np.testing.assert_allclose(ours, np.asarray(hbjax.simulate(model, v, xi)), atol=1e-9)


def test_base_systems_are_valid():
    rng = np.random.default_rng(1)
    seen = collections.Counter()
    for _ in range(60):
        b = random_base(rng)
        seen[(b["na"], b["m"])] += 1
        assert 1 <= b["na"] <= 4 and 1 <= b["nb"] <= 4 and 2 <= b["m"] <= 4
        assert np.max(np.abs(np.roots(np.r_[1.0, b["a"]]))) < 1  # stable
        np.testing.assert_allclose(b["b"].sum() / (1 + b["a"].sum()), 1.0, rtol=1e-12)
        grid = np.linspace(-b["amp"], b["amp"], 101)
        gap = np.polyval(b["c2"][::-1], grid) - np.polyval(b["c1"][::-1], grid)
        assert np.all(gap > 0)  # P1 below P2: a rising input rides on P1
    assert len({na for na, _ in seen}) == 4 and len({m for _, m in seen}) == 3


def test_clean_cases_are_nominal_simulation_plus_white_noise():
    rng = np.random.default_rng(2)
    for kind in INPUT_KINDS:
        c = concealed_case(rng, None, input_kind=kind)
        assert N_MIN <= len(c["v"]) <= N_MAX and c["channels"] == {} and c["size"] == 0
        y_model = np.asarray(hbjax.simulate(c["nominal_model"], c["v"], c["noise"]))
        np.testing.assert_allclose(c["y"], y_model, atol=1e-9 * spread(c["y"]))
        assert _whiteness_z(c["noise"]) < 4.5
        noise_out = c["y"] - np.asarray(hbjax.simulate(c["nominal_model"], c["v"]))
        frac = np.std(noise_out) / spread(c["y_nominal_free"])
        assert 0.5 * NOISE_MIN < frac < 2 * NOISE_MAX


@pytest.mark.parametrize("effect", [e for e in ALL_EFFECTS if e != "colored_noise"])
def test_effect_changes_the_output_detectably(effect):
    for c in _cases(effect, 2, seed=10 + ALL_EFFECTS.index(effect)):
        assert c["effect"] == effect and 0 <= c["size"] <= 1
        y_nom = np.asarray(hbjax.simulate(c["nominal_model"], c["v"]))
        change = np.sqrt(np.mean((c["y_free"] - y_nom) ** 2))
        assert change >= 0.95 * RATIO_MIN * c["sigma_y"], (effect, change / c["sigma_y"])
        # The measured record departs from the nominal simulation by more than its noise.
        resid = c["y"] - np.asarray(hbjax.simulate(c["nominal_model"], c["v"], c["noise"]))
        assert np.sqrt(np.mean(resid ** 2)) > 0.5 * RATIO_MIN * c["sigma_y"]
        assert np.all(np.isfinite(c["y"]))
        assert (effect == "missing_input") == bool(c["channels"])


def test_colored_noise_is_coloured_and_deterministic_part_nominal():
    for c in _cases("colored_noise", 3, seed=40):
        y_nom = np.asarray(hbjax.simulate(c["nominal_model"], c["v"], c["noise"]))
        np.testing.assert_allclose(c["y"], y_nom, atol=1e-9 * spread(c["y"]))
        assert _whiteness_z(c["noise"]) > 6


def test_missing_input_channel_drives_the_output():
    for c in _cases("missing_input", 2, seed=41):
        (w,) = c["channels"].values()
        assert w.shape == c["v"].shape and np.std(w) > 0
        y_w = arx(w, np.zeros(len(w)), c["base"]["a"], c["truth"]["b_aux"])
        resid = c["y"] - np.asarray(hbjax.simulate(c["nominal_model"], c["v"], c["noise"]))
        np.testing.assert_allclose(resid, y_w, atol=1e-9 * spread(c["y"]))


def test_harmonic_distortion_is_a_line_at_a_harmonic_of_a_pure_sine():
    rng = np.random.default_rng(42)
    c = concealed_case(rng, "harmonic_distortion", input_kind="multisine", n=4000)
    extra = c["y_free"] - np.asarray(hbjax.simulate(c["nominal_model"], c["v"]))
    # A static function of v: identical input values give identical additions.
    v_round = np.round(c["v"], 12)
    _, inverse = np.unique(v_round, return_inverse=True)
    for k in range(5):
        same = extra[inverse == inverse[k]]
        assert np.ptp(same) < 1e-9 * np.ptp(extra) + 1e-12
    assert c["truth"]["frequency"] == pytest.approx(c["truth"]["order"] * c["f0"])


def test_generator_is_deterministic_and_rejects_unknown_effects():
    a = concealed_case(np.random.default_rng(7), "coulomb_friction")
    b = concealed_case(np.random.default_rng(7), "coulomb_friction")
    np.testing.assert_array_equal(a["y"], b["y"])
    with pytest.raises(ValueError, match="effect"):
        concealed_case(np.random.default_rng(0), "gremlins")


def _diagnose(case):
    kwargs = {}
    if case["channels"] and "channels" in inspect.signature(hbjax.diagnose).parameters:
        kwargs["channels"] = case["channels"]
    return hbjax.diagnose(case["nominal_model"], case["v"], case["y"], **kwargs)


@pytest.fixture(scope="module")
def independent_sample():
    """A small sample: one case per effect, three clean ones, two base structures and one
    record length (so that compiled solvers are shared); benchmarks/diagnose_suite.py runs
    the full variety. Returns ``({effect: [top finding]}, [findings per clean case])``."""
    rng = np.random.default_rng(2024)
    structures = [dict(na=2, nb=2, m=3), dict(na=3, nb=2, m=2)]

    def case(effect, i):
        return concealed_case(rng, effect, n=1500, base=random_base(rng, **structures[i % 2]))

    tops = collections.defaultdict(list)
    for i, effect in enumerate(ALL_EFFECTS):
        d = _diagnose(case(effect, i))
        tops[effect].append(d.best.effect if d.best is not None else None)
    clean_findings = [len(_diagnose(case(None, i)).findings) for i in range(3)]
    return tops, clean_findings


@pytest.mark.slow
def test_diagnosis_on_independent_cases_holds_its_measured_level(independent_sample):
    # Measured on this sample: 13 of 15 effects named (12 before the refit's seen branch
    # directions and the held-out ordering, 11 before the anchored variants)
    # and no finding on the clean records (benchmarks/RESULTS.md lists the misses of the
    # large study, not this sample's). The floor sits two cases below, so the test fails
    # on a regression, not on one borderline decision moving.
    tops, clean_findings = independent_sample
    overall = np.mean([t == e for e, ts in tops.items() for t in ts])
    assert overall >= 10 / 15, (overall, dict(tops))
    assert max(clean_findings) <= 1, clean_findings  # the clean-record target, met


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the targets (top-1 >= 95% overall, >= 85% per "
                   "effect) on this one-case-per-effect sample need 15 of 15; it gives 13. "
                   "The study of 300 cases meets them (97.3%, every effect >= 90%: "
                   "benchmarks/RESULTS.md)")
def test_diagnosis_accuracy_target_on_independent_cases(independent_sample):
    tops, _ = independent_sample
    hits = {e: sum(t == e for t in ts) / len(ts) for e, ts in tops.items()}
    overall = np.mean([t == e for e, ts in tops.items() for t in ts])
    assert overall >= 0.95, (overall, dict(tops))
    assert min(hits.values()) >= 0.85, hits
