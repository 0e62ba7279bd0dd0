"""Readable models and results: reprs with numbers, summaries, Jupyter HTML."""

import dataclasses
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax


@pytest.fixture(scope="module")
def records():
    model = hbjax.default_system()
    v = jax.random.uniform(jax.random.key(0), (1500,), minval=-2.0, maxval=2.0)
    noise = 0.02 * jax.random.normal(jax.random.key(1), (1500,))
    return model, np.asarray(v), np.asarray(hbjax.simulate(model, v, noise))


@pytest.fixture(scope="module")
def refined(records):
    model, v, y = records
    return hbjax.refine(model, (v, y))


def _numbers(text):
    return [float(x) for x in re.findall(r"-?\d+\.?\d*(?:e[-+]?\d+)?", text)]


def test_model_repr_shows_values_and_html_table(system):
    text = repr(system)
    assert "f64[" not in text
    assert "a=[-1.2, 0.5]" in text and "b=[1, 0.5]" in text
    assert "c1=[-1, 0.9, 0.01]" in text
    assert repr(system.backlash) == "Backlash(c1=[-1, 0.9, 0.01], c2=[1, 0.9, -0.01])"
    html = system._repr_html_()
    assert html.count("<tr>") == 1 + len(hbjax.param_names(system))
    assert "<td style='text-align:left'>c2_2</td><td style='text-align:right'>-0.01</td>" in html


def test_traced_and_batched_models_fall_back_to_shapes(system):
    seen = []

    @jax.jit
    def f(model):
        seen.append(repr(model))
        return model.arx.a

    f(system)
    assert seen and "a=f64[2]" in seen[0] and "c1=f64[3]" in seen[0]
    batch = jax.vmap(lambda s: eqx.tree_at(lambda m: m.arx.b, system, system.arx.b * s))(
        jnp.linspace(1.0, 2.0, 20))
    assert "b=f64[20,2] in [0.5, 2]" in repr(batch)
    html = batch._repr_html_()
    assert "mean over 20" in html
    # b1 runs over 1..2: mean 1.5
    assert "<td style='text-align:left'>b1</td><td style='text-align:right'>1.5</td>" in html


def test_refine_result_repr_and_summary(refined):
    text = repr(refined)
    assert "RESULTS<" not in text and "result='successful'" in text
    assert "a=[" in text and "noise_std=" in text
    summary = refined.summary()
    assert isinstance(summary, str)
    names = hbjax.param_names(refined.model)
    theta = np.asarray(hbjax.flatten_params(refined.model))
    std = np.asarray(refined.std)
    rows = {line.split()[0]: line for line in summary.splitlines()
            if line.split() and line.split()[0] in names}
    assert list(rows) == names
    for name, est, sd in zip(names, theta, std):
        value, se, lo, hi = _numbers(rows[name].split(maxsplit=1)[1])[:4]
        assert value == pytest.approx(est, rel=1e-3, abs=1e-12)
        assert se == pytest.approx(sd, rel=1e-3)
        assert lo == pytest.approx(est - 1.96 * sd, rel=2e-3, abs=1e-3 * sd)
        assert hi == pytest.approx(est + 1.96 * sd, rel=2e-3, abs=1e-3 * sd)
    assert "result: success" in summary
    assert "understate the error" not in summary
    assert re.search(r"noise std \(criterion's residuals\)\s*: 0\.0(19|2)", summary)
    html = refined._repr_html_()
    assert html.startswith("<div>") and "95% interval" in html and "<table>" in html


def test_a_success_whose_branches_cross_says_its_errors_may_be_understated(refined):
    # (an outside probe: branches pressed together at a recorded level, errors 8-34 of the
    # reported standard errors, shown as a plain success)
    assert not bool(refined.branches_cross)
    crossed = dataclasses.replace(refined, branches_cross=jnp.asarray(True))
    assert "can understate the error" in crossed.summary()
    assert "can understate the error" in crossed._repr_html_()
    failed = dataclasses.replace(crossed, result=hbjax.RESULTS.poor_fit)
    assert "understate" not in failed.summary()  # a failure's message says what is wrong


def test_unidentified_parameters_are_flagged(refined):
    if not hasattr(refined, "identified"):
        pytest.skip("results without identifiability flags")
    flags = jnp.asarray([n == "c2_2" for n in hbjax.param_names(refined.model)])
    marked = eqx.tree_at(lambda r: r.identified, refined, ~flags)
    line = [ln for ln in marked.summary().splitlines() if ln.startswith("c2_2")][0]
    assert line.rstrip().endswith("unidentified")
    other = [ln for ln in marked.summary().splitlines() if ln.startswith("c2_1")][0]
    assert "unidentified" not in other


def test_a_parameter_the_normalisation_sets_reads_fixed_not_std_err_0():
    # nb = 1 under B(1) = 1: b1 = 1 exactly, its standard error 0; the table must not
    # print it as a perfect estimate.
    system = hbjax.Hammerstein(hbjax.default_system().backlash, hbjax.ARX(a=[-0.6], b=[0.4]))
    v = np.asarray(jax.random.uniform(jax.random.key(2), (800,), minval=-6.0, maxval=6.0))
    y = np.asarray(hbjax.simulate(system, v, 0.01 * jax.random.normal(jax.random.key(3), (800,))))
    res = hbjax.fit((v, y), na=1, nb=1, m=3, key=jax.random.key(0), progress=False,
                    throw=False)
    assert float(res.std[1]) == 0.0  # b1: set, not estimated
    line = [ln for ln in str(res.summary()).splitlines() if ln.startswith("b1 ")][0]
    assert "fixed" in line and "set by the normalisation" in line, line
    other = [ln for ln in str(res.summary()).splitlines() if ln.startswith("a1 ")][0]
    assert "fixed" not in other and "[" in other


def test_batched_result_codes_are_counted(refined):
    codes = jnp.asarray([refined.result._value] * 3)
    batched = eqx.tree_at(lambda r: r.result._value, refined, codes)
    assert "result={'successful': 3}" in repr(batched)
    assert "result: {'successful': 3}" in str(batched.summary())


def test_a_batched_closed_form_summary_counts_its_codes(design):
    """identify_giri under vmap: its batched `.message` is an array of strings, which
    summary() once printed as the result line (`result: ['' '']`)."""
    model = hbjax.default_system()
    N = 1200
    vs = [design.constant_input(N), design.binary_input(N), design.staircase_input(N)]
    noise = 0.01 * jax.random.normal(jax.random.key(2), (2, N))
    ys = [jnp.stack([hbjax.simulate(model, v, e) for e in noise]) for v in vs]
    batched = jax.vmap(lambda a, b, c: hbjax.identify_giri(design, a, b, c, throw=False))(*ys)
    assert "result: {'successful': 2}" in str(batched.summary())


def test_giri_and_crlb_summaries(design):
    model = hbjax.default_system()
    N = 1200
    vs = [design.constant_input(N), design.binary_input(N), design.staircase_input(N)]
    res = hbjax.identify_giri(design, *(hbjax.simulate(model, v) for v in vs))
    text = res.summary()
    assert "gap P2*(-h_m) - P1*(h_m) (1 expected) : 1" in text
    assert "result: success" in text and "95% interval" not in text
    assert "rows_ls=" in repr(res) and "result='successful'" in repr(res)
    model = hbjax.normalise_static_gain(model)
    bound = hbjax.crlb(model, (vs[2], hbjax.simulate(model, vs[2])), noise_std=0.1)
    names = hbjax.param_names(model)
    text = bound.summary(names=names)
    first = [ln for ln in text.splitlines() if ln.startswith("a1")][0]
    assert _numbers(first.split(maxsplit=1)[1])[0] == pytest.approx(float(bound.std[0]), rel=1e-3)
    assert "theta1" in bound.summary()


def test_study_summary_reports_intervals():
    rng = np.random.default_rng(0)
    true = np.array([0.5, 2.0])
    est = true + rng.standard_normal((2, 50, 2)) * np.array([[[0.2]], [[0.1]]])
    codes = np.zeros((2, 50), int)
    codes[0, :3] = 2
    study = hbjax.Study.from_estimates(
        [100, 400], ["a1", "b1"], true, est, codes, keep_estimates=False,
        compile_seconds=np.zeros(2), run_seconds=np.zeros(2), realisations=50,
        noise_std=0.1, estimator="giri", noise="white", n_devices=1, chunk_size=50)
    text = study.summary()
    row = [ln for ln in text.splitlines() if ln.startswith("b1")][0]
    true_, mean, se, lo, hi = _numbers(row.split(maxsplit=1)[1])[:5]
    assert mean == pytest.approx(study.mean[1, 1], rel=1e-3)
    assert se == pytest.approx(study.std[1, 1] / np.sqrt(50), rel=1e-3)
    # Student's t with 49 degrees of freedom (2.0096), not the normal 1.96
    assert lo < mean < hi and hi - lo == pytest.approx(2 * 2.0096 * se, rel=1e-2)
    assert "valid realisations : [47, 50] of 50" in text
    assert "failed (" in text
    assert "estimates" not in repr(study) and "slope=" in repr(study)


def test_diagnosis_summary_is_text_and_html(system):
    finding = hbjax.Finding(
        effect="output_saturation", physics="the output clips", where={"windows": [[5, 9]]},
        parameters={"high": 1.5}, model=system, metric="simulation", fit_before=61.25,
        fit_after=88.5, evidence={"reference": "nominal", "delta_bic_vs_nominal": -42.0,
                                  "dm_z": 5.5})
    tests = {"whiteness": {"p_value": 0.001, "lags_outside": 4},
             "independence": {"p_value": 0.002}}
    d = hbjax.Diagnosis(True, [finding], tests, {}, 700, 300, system, verdict="explained")
    text = d.summary()
    assert isinstance(text, str) and "61.2% -> 88.5%" in text
    html = d._repr_html_()
    assert "<td style='text-align:right'>88.5</td>" in html and "-42" in html
    assert repr(d) == ("Diagnosis(verdict='explained', best='output_saturation', findings="
                       "['output_saturation'], n_fit=700, n_holdout=300)")
    assert d.unconverged == () and "step limit" not in text


def test_diagnosis_names_candidates_stopped_at_the_step_limit(system):
    tests = {"whiteness": {"p_value": 1e-6, "lags_outside": 4},
             "independence": {"p_value": 0.5}}
    candidates = {
        "extra_delay": {"lm_steps": 45, "lm_converged": False},
        "offset_drift": {"lm_steps": 12, "lm_converged": True},
        "coulomb_friction": {"lm_steps": 45, "lm_converged": False},
        "branch_degree": {"lm_steps": 3, "lm_converged": False},  # failed: listed there
        "nominal": {"bic": -10.0},
    }
    d = hbjax.Diagnosis(True, [], tests, candidates, 700, 300, system, verdict="unexplained",
                        failed={"branch_degree": "the fit ended at NaN parameters (3 solver steps)"})
    assert d.unconverged == ("extra_delay", "coulomb_friction")
    text = d.summary()
    assert ("Stopped at the solver's step limit (45 steps) before converging, judged where "
            "they stopped: extra_delay, coulomb_friction.") in text
    assert d.to_dict()["unconverged"] == ["extra_delay", "coulomb_friction"]
