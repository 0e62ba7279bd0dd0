"""`fit`'s default criterion "auto" (hbjax/_identify/fit_criterion.py), on random paper-class
systems of the independent generator: the prediction result stands under equation noise,
and noise at the sensor, which biases it, is answered by the output-error refinement."""

import dataclasses

import jax
import numpy as np
import pytest

import hbjax
from generators.paper_class import INPUT_KINDS, random_input, random_paper_system, simulate_numpy
from generators.paper_runs import noise_gain

pytestmark = pytest.mark.slow


def _validation_fit(model, v, y):
    return float(np.atleast_1d(hbjax.compare(model, v, y).fit)[0])


def test_auto_keeps_the_prediction_criterion_under_equation_noise_and_leaves_it_under_output_noise():
    # (inputs that move through their range: a few PRBS levels determine the branches only
    # at the levels, which fit refuses whatever the noise)
    kinds = [kind for kind in INPUT_KINDS if kind != "prbs_levels"]
    rng = np.random.default_rng(2024)
    gains, switched = [], 0
    for k in range(4):
        s = random_paper_system(rng, n=int(rng.integers(1, 4)), m=3)
        kind = kinds[k % len(kinds)]
        v = random_input(rng, kind, 2000, 1.5 * s["h_m"])
        y_clean = simulate_numpy(s, v)[0]
        v_val = random_input(rng, kind, 1500, 1.5 * s["h_m"])
        y_val = simulate_numpy(s, v_val)[0]
        sd = 0.03 * np.ptp(y_clean)
        fit = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(k), progress=False)

        # Equation noise: the paper's model (eq. (10)) holds, the one-step errors are white
        # and the prediction criterion (its maximum likelihood) is kept.
        y_eq = simulate_numpy(s, v, sd / noise_gain(s["a"]) * rng.standard_normal(v.size))[0]
        res = hbjax.fit((v, y_eq), **fit)
        assert res.criterion == "prediction", res.criterion_choice
        assert res.criterion_choice == "auto: prediction (its one-step errors are white)"
        assert float(res.prediction_whiteness_p) >= 1e-3

        # Noise at the output: the prediction optimum is biased (errors in variables).
        y_out = y_clean + sd * rng.standard_normal(v.size)
        auto = hbjax.fit((v, y_out), **fit)
        pred = hbjax.fit((v, y_out), criterion="prediction", **fit)
        assert auto.result == hbjax.RESULTS.successful
        if auto.criterion == "simulation":
            switched += 1
            assert "coloured" in auto.criterion_choice
            assert float(auto.prediction_whiteness_p) < 1e-3
            assert "criterion chosen" in str(auto.summary())
            # asked for, the prediction criterion's result is kept and says what is wrong
            assert pred.criterion == "prediction"
            assert pred.criterion_choice.startswith(
                "prediction, as asked; its one-step errors are coloured"), pred.criterion_choice
        gains.append(_validation_fit(auto.model, v_val, y_val)
                     - _validation_fit(pred.model, v_val, y_val))
    gains = np.array(gains)
    assert switched >= 3, gains
    # never worse on the held-out record, better on average
    assert np.all(gains > -0.5) and np.mean(gains) > 1.0, gains


def test_auto_is_refused_where_only_the_two_criteria_are_meant():
    v = np.sin(0.05 * np.arange(400))
    with pytest.raises(ValueError, match=r"`criterion` must be one of \('prediction', 'simulation'\)"):
        hbjax.refine(hbjax.default_system(), [(v, v)], criterion="auto")
    with pytest.raises(ValueError, match=r"`criterion` must be one of \('auto', 'prediction', 'simulation'\)"):
        hbjax.fit((v, v), na=1, nb=1, m=2, key=jax.random.key(0), criterion="equation")


def _output_noise_record(seed, n):
    """The default system (``A = 1 - 1.2 q^-1 + 0.5 q^-2``: sensor noise ``w`` reaches its
    one-step errors as ``A w``, lag-one correlation -0.67), random steps, noise 3 % of the
    output's range at the output."""
    rng = np.random.default_rng(seed)
    system = hbjax.default_system()
    v = np.repeat(rng.uniform(-6, 6, n), rng.integers(1, 20, n))[:n]
    y_clean = np.asarray(hbjax.simulate(system, v))
    s = dict(na=2, nb=2)
    return s, v, y_clean, y_clean + 0.03 * np.ptp(y_clean) * rng.standard_normal(n)


def test_auto_tests_whiteness_without_the_records_too_short_for_it():
    # A 20-sample record beside a long one made the pooled p-value NaN, read as white.
    s, v, _, y = _output_noise_record(11, 1500)
    fit = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(0), progress=False,
               throw=False)
    alone = hbjax.fit((v, y), **fit)
    both = hbjax.fit([(v, y), (v[:20], y[:20])], **fit)
    assert alone.criterion == "simulation", alone.criterion_choice
    assert both.criterion == "simulation", both.criterion_choice
    assert np.isfinite(float(both.prediction_whiteness_p))
    short = hbjax.fit((v[:40], y[:40]), na=1, nb=1, m=2, key=jax.random.key(0),
                      progress=False, throw=False)
    if short.result == hbjax.RESULTS.successful:
        assert short.criterion_choice.startswith("auto: prediction (no record long enough")


def test_auto_does_not_read_rounding_as_coloured_errors():
    s, v, y_clean, _ = _output_noise_record(12, 800)
    res = hbjax.fit((v, y_clean), na=s["na"], nb=s["nb"], m=3, key=jax.random.key(0),
                    progress=False)
    assert res.criterion == "prediction"
    assert res.criterion_choice == ("auto: prediction (its one-step errors are rounding: "
                                    "noise-free records)")


def _refuse_output_error_results(monkeypatch):
    """Make `fit`'s free-run judgement refuse every output-error (simulation) result."""
    import hbjax._identify.fit as fit_module

    judge = fit_module.judge_free_run

    def refuse_output_error(res, recordings):
        res = judge(res, recordings)
        if res.criterion == "simulation":
            return dataclasses.replace(res, result=hbjax.RESULTS.free_run_undetermined)
        return res

    monkeypatch.setattr(fit_module, "judge_free_run", refuse_output_error)


def test_auto_keeps_the_prediction_success_when_the_adopted_refinement_is_refused(monkeypatch):
    # fit judges the output-error refinement as it judges its best start; where that
    # refuses it, the prediction criterion's success is reported, saying why.
    _refuse_output_error_results(monkeypatch)
    s, v, _, y = _output_noise_record(11, 1500)
    res = hbjax.fit((v, y), na=s["na"], nb=s["nb"], m=3, key=jax.random.key(0),
                    progress=False)
    assert res.result == hbjax.RESULTS.successful and res.criterion == "prediction"
    assert res.criterion_choice.startswith("auto: prediction kept; its one-step errors are "
                                           "coloured, but the output-error criterion gave "
                                           "no success")


def test_the_output_error_results_compete_by_cost_as_fits_starts_do():
    # The refinement from the prediction optimum and the output-error search are judged
    # as fit judges its best start: the lower cost wins among the screened results, and a
    # success at a higher cost than a refused optimum is a local minimum, not a success
    # (a BRFD record: the refinement at 59.8 % beside the search's refused 67.7 %).
    from types import SimpleNamespace

    from hbjax._identify.fit_criterion import _better

    R = hbjax.RESULTS

    def result(code, fit):
        return SimpleNamespace(result=code, sim_fit_pooled=fit)

    samples = 1000
    out, searched = result(R.successful, 59.8), result(R.branches_undetermined, 67.7)
    assert _better(out, searched, samples) is searched  # refused: no success
    out, searched = result(R.branches_undetermined, 59.8), result(R.successful, 67.7)
    assert _better(out, searched, samples) is searched
    out, searched = result(R.successful, 67.7), result(R.loop_unresolved, 59.8)
    assert _better(out, searched, samples) is out
    # an unscreened refusal (unstable, below the floor) does not compete
    out, searched = result(R.successful, 59.8), result(R.unstable, 67.7)
    assert _better(out, searched, samples) is out
    assert _better(result(R.unstable, 1.0), result(R.poor_fit, 2.0), samples) is None
    # within 2 sigma^2 of each other: the same optimum, the refinement kept
    e = 1.0 - 0.9
    within = 100.0 * (1.0 - e / np.sqrt(1.0 + 1.0 / samples))
    beyond = 100.0 * (1.0 - e / np.sqrt(1.0 + 3.0 / samples))
    out = result(R.successful, 90.0)
    assert _better(out, result(R.branches_between_levels, within), samples) is out
    assert _better(out, result(R.branches_between_levels, beyond), samples).result != R.successful


def test_the_package_own_searches_skip_the_whiteness_note_they_never_show(monkeypatch):
    # select_structure's rows and refine's restarts fit with an explicit prediction
    # criterion; the whiteness test is only the note of `criterion_choice` there.
    import hbjax._identify.fit_criterion as criterion_module

    calls = []
    tested = criterion_module.prediction_whiteness

    def counted(*args, **kwargs):
        calls.append(1)
        return tested(*args, **kwargs)

    monkeypatch.setattr(criterion_module, "prediction_whiteness", counted)
    s, v, _, y = _output_noise_record(11, 600)
    table = hbjax.select_structure((v, y), na=2, nb=2, m=3, key=jax.random.key(0),
                                   progress=False)
    assert table.best == (2, 2, 3) and calls == []
    res = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.key(0), criterion="prediction",
                    progress=False, throw=False)
    assert len(calls) == 1
    assert res.criterion_choice.startswith("prediction, as asked; its one-step errors are "
                                           "coloured"), res.criterion_choice


def _benchmark_case(seed, system, level, where, levels=(0.05, 0.2), T=2000):
    """The records of ``benchmarks/fit_criterion.py --systems N --levels 0.05,0.2 --T 2000
    --seed S``, its system `system` at noise `level` (`where`: "equation" or "output"):
    the system, the estimation record, and the noise-free validation record."""
    rng = np.random.default_rng(seed)
    for k in range(system + 1):
        s = random_paper_system(rng, n=int(rng.integers(1, 4)), m=3)
        kind = INPUT_KINDS[k % len(INPUT_KINDS)]
        v = random_input(rng, kind, T, 1.5 * s["h_m"])
        y_clean = simulate_numpy(s, v)[0]
        v_val = random_input(rng, kind, 2000, 1.5 * s["h_m"])
        y_val = simulate_numpy(s, v_val)[0]
        for lv in levels:
            for at in ("equation", "output"):
                noise = rng.standard_normal(T) * lv * np.ptp(y_clean)
                if k == system and (lv, at) == (level, where):
                    y = (y_clean + noise if at == "output"
                         else simulate_numpy(s, v, noise / noise_gain(s["a"]))[0])
                    return s, (v, y), (v_val, y_val)
    raise AssertionError("no such case")


def test_auto_reads_sensor_noise_that_the_biased_prediction_optimum_whitens():
    # 20 % sensor noise, na = 1: the prediction optimum's one-step errors look white
    # (its `a` is pulled towards 0), yet it validates at 92.9 % against the output-error
    # optimum's 97.8 %; that optimum's free-run errors are white and its one-step errors
    # coloured.
    s, rec, val = _benchmark_case(5, 3, 0.2, "output")
    kw = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(3), progress=False)
    auto = hbjax.fit(rec, **kw)
    pred = hbjax.fit(rec, criterion="prediction", **kw)
    assert float(pred.prediction_whiteness_p) >= 1e-3  # white: the first reading misses it
    assert auto.criterion == "simulation", auto.criterion_choice
    assert auto.criterion_choice.startswith("auto: simulation (output error)")
    assert "the output-error optimum's free-run errors are white and its one-step errors " \
        "coloured" in auto.criterion_choice
    assert _validation_fit(auto.model, *val) > _validation_fit(pred.model, *val) + 3.0


def test_a_refusal_under_sensor_noise_carries_the_prediction_whiteness_p(monkeypatch):
    # The record of the test above, the output-error judgement refused: "auto" returns
    # the refusal, and it still says how white the prediction optimum's errors were.
    s, rec, _ = _benchmark_case(5, 3, 0.2, "output")
    kw = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(3), progress=False,
              throw=False)
    pred = hbjax.fit(rec, criterion="prediction", **kw)
    _refuse_output_error_results(monkeypatch)
    auto = hbjax.fit(rec, **kw)
    assert auto.result == hbjax.RESULTS.free_run_undetermined
    assert auto.criterion_choice.startswith("auto: simulation (output error): the "
                                            "refinement from the prediction optimum reads "
                                            "noise at the sensor"), auto.criterion_choice
    assert float(auto.prediction_whiteness_p) == pytest.approx(
        float(pred.prediction_whiteness_p), rel=1e-6)
    assert float(auto.prediction_whiteness_p) >= 1e-3


def test_auto_never_keeps_a_biased_prediction_success_once_the_noise_reads_as_the_sensors():
    # 20 % sensor noise, the true model's own free-run fit on the record 1.6 %: the
    # prediction optimum "succeeded" at 0.8 % and validated at -3.6 %; the output-error
    # refinement reads the sensor noise. Its free run is barely determined by the record
    # (a borderline judgement: refused under the package's compiler settings, a success
    # validating at 55 % or so under the test suite's), so either answer is honest, but
    # not the biased optimum.
    s, rec, val = _benchmark_case(5, 5, 0.2, "output")
    kw = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(5), progress=False,
              throw=False)
    pred = hbjax.fit(rec, criterion="prediction", **kw)
    assert pred.result == hbjax.RESULTS.successful and _validation_fit(pred.model, *val) < 0
    auto = hbjax.fit(rec, **kw)
    assert auto.criterion == "simulation", auto.criterion_choice
    if auto.result == hbjax.RESULTS.successful:
        assert _validation_fit(auto.model, *val) > 40.0
        assert "noise at the sensor" in auto.criterion_choice
    else:
        assert "the output-error criterion gave no success" in auto.criterion_choice
        with pytest.raises(hbjax.RefinementError):
            hbjax.fit(rec, **dict(kw, throw=True))


def test_auto_searches_with_the_output_error_criterion_where_prediction_finds_no_success():
    s, rec, val = _benchmark_case(5, 0, 0.2, "output")  # na = 3, 20 % sensor noise
    kw = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(0), progress=False,
              throw=False)
    pred = hbjax.fit(rec, criterion="prediction", **kw)
    assert pred.result != hbjax.RESULTS.successful
    auto = hbjax.fit(rec, **kw)
    sim = hbjax.fit(rec, criterion="simulation", **kw)
    assert auto.result == hbjax.RESULTS.successful and auto.criterion == "simulation"
    assert auto.criterion_choice.startswith("auto: simulation (output error), from its own "
                                            "multi-start search"), auto.criterion_choice
    assert float(auto.stats["cost"]) == float(sim.stats["cost"])
    assert _validation_fit(auto.model, *val) > 80.0
    # with it raised, the advice no longer suggests the criterion already tried
    with pytest.raises(hbjax.RefinementError) as raised:
        hbjax.fit(rec, **dict(kw, throw=True, starts=1, max_steps=1))
    assert "criterion='simulation'" not in str(raised.value)


def test_auto_keeps_a_prediction_failure_whose_one_step_errors_are_white():
    # A closing loop under equation noise that the records do not pin: the equation-error
    # model holds, so the refusal is the records' and the output-error search's result is
    # not reported (it gave successes validating at 90-99 % there).
    from generators.paper_class import random_closing_loop_system

    rng = np.random.default_rng(3)
    for attempt in range(12):
        s = random_closing_loop_system(rng, m=3)
        v = random_input(rng, "multisine", 600, s["scale"])
        y_clean = simulate_numpy(s, v)[0]
        sd = 0.05 * np.ptp(y_clean)
        y = simulate_numpy(s, v, sd / noise_gain(s["a"]) * rng.standard_normal(v.size))[0]
        kw = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(attempt), progress=False,
                  throw=False, starts=16)
        res = hbjax.fit((v, y), **kw)
        if res.result != hbjax.RESULTS.successful and res.criterion_choice:
            break
    else:
        pytest.fail("no refused fit among the draws")
    assert res.criterion == "prediction"
    assert float(res.prediction_whiteness_p) >= 1e-3, res.criterion_choice
    assert res.criterion_choice.startswith("auto: prediction; no start succeeded, and the "
                                           "noise reads as the equation's")


def test_select_structure_can_choose_its_criterion_as_fit_does():
    # Sensor noise: "auto" is chosen once, on the largest structure, and every row is
    # fitted and scored with it (one criterion's losses in one table).
    s, v, _, y = _output_noise_record(11, 1500)
    sel = hbjax.select_structure((v, y), na=[1, 2, 3], nb=2, m=3, key=jax.random.key(0),
                                 criterion="auto", progress=False)
    assert sel.criterion == "simulation"
    assert sel.criterion_choice.startswith("auto: simulation"), sel.criterion_choice
    assert "chosen on the largest structure" in str(sel.summary())
    assert sel.best == (2, 2, 3)
    with pytest.raises(ValueError, match=r"`criterion` must be one of \('auto', 'prediction', 'simulation'\)"):
        hbjax.select_structure((v, y), na=2, nb=2, m=3, key=jax.random.key(0),
                               criterion="output", progress=False)


def test_select_structure_scores_the_largest_row_with_autos_own_prediction_fit(monkeypatch):
    # Equation noise: "auto" keeps the prediction criterion on the largest structure; that
    # fit is the largest row's own (same key and starts), so it is not fitted twice.
    import hbjax._identify.structure as structure_module

    rng = np.random.default_rng(7)
    s = random_paper_system(rng, n=2, m=3)
    v = random_input(rng, "multisine", 800, 1.5 * s["h_m"])
    sd = 0.03 * np.ptp(simulate_numpy(s, v)[0])
    y = simulate_numpy(s, v, sd / noise_gain(s["a"]) * rng.standard_normal(v.size))[0]
    calls = []
    fit_unnoted = structure_module.fit_unnoted

    def counted(*args, **kwargs):
        calls.append((kwargs["na"], kwargs.get("criterion", "auto")))
        return fit_unnoted(*args, **kwargs)

    monkeypatch.setattr(structure_module, "fit_unnoted", counted)
    kw = dict(nb=s["nb"], m=3, key=jax.random.key(0), progress=False)
    sel = hbjax.select_structure((v, y), na=[1, s["na"]], criterion="auto", **kw)
    assert sel.criterion == "prediction", sel.criterion_choice
    assert calls == [(s["na"], "auto"), (1, "prediction")]
    alone = hbjax.fit((v, y), na=s["na"], criterion="prediction", **kw)
    row = sel.orders.index((s["na"], s["nb"], 3))
    np.testing.assert_array_equal(hbjax.flatten_params(sel.models[row]),
                                  hbjax.flatten_params(alone.model))
    assert bool(sel.success[row]) == (alone.result == hbjax.RESULTS.successful)
