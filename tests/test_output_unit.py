"""Refinement does not depend on the unit of the output.

Random systems of the paper's class from the independent generator (``tests.generators``),
random inputs, an output unit drawn log-uniformly over 1e-9..1e9: the refined model, its
free-run fit, its standard errors and its result code are those of the same records in
units, carried by the unit. (The solver's tolerances are absolute; before the output was
taken to its own unit a record in micro-units stopped at its start and said "success", and
one in mega-units halved its standard errors.)
"""

import numpy as np
import pytest

import hbjax
from tests.generators.paper_class import INPUT_KINDS
from tests.generators.paper_runs import ordinary_record_and_start, output_unit_weights


def _case(seed):
    rng = np.random.default_rng(seed)
    sys, v, y, start = ordinary_record_and_start(
        rng, T=500, kind=INPUT_KINDS[seed % len(INPUT_KINDS)], m=int(rng.integers(2, 4)))
    return sys, v, y, start, float(10.0 ** rng.uniform(-9, 9))


def _in_unit(model, unit):
    bl = model.backlash
    return hbjax.Hammerstein(hbjax.Backlash(np.asarray(bl.c1) * unit, np.asarray(bl.c2) * unit),
                             model.arx)


def _assert_same_up_to_unit(base, scaled, unit):
    assert str(base.result) == str(scaled.result), (base.message, scaled.message)
    assert float(scaled.sim_fit_pooled) == pytest.approx(float(base.sim_fit_pooled), abs=1e-5)
    w = output_unit_weights(base, unit)
    theta, theta_u = np.asarray(hbjax.flatten_params(base.model)), np.asarray(
        hbjax.flatten_params(scaled.model)) / w
    np.testing.assert_allclose(theta_u, theta, rtol=1e-5, atol=1e-7 * np.max(np.abs(theta)))
    assert base.unidentified == scaled.unidentified
    ok = np.isfinite(np.asarray(base.std))
    np.testing.assert_allclose(np.asarray(scaled.std)[ok] / w[ok], np.asarray(base.std)[ok],
                               rtol=1e-4)
    assert float(scaled.noise_std) / unit == pytest.approx(float(base.noise_std), rel=1e-6)
    assert float(scaled.stats["cost"]) / unit**2 == pytest.approx(float(base.stats["cost"]),
                                                                  rel=1e-6)


@pytest.mark.parametrize("seed", [11, 12, 13])
@pytest.mark.parametrize("gauge", ["static_gain", "paper"])
def test_refine_is_the_same_in_any_output_unit(seed, gauge):
    sys, v, y, start, unit = _case(seed)
    h_m = sys["h_m"] if gauge == "paper" else None
    base = hbjax.refine(start, (v, y), h_m=h_m, throw=False)
    scaled = hbjax.refine(_in_unit(start, unit), (v, y * unit), h_m=h_m, throw=False)
    assert base.gauge == gauge
    assert base.result == hbjax.RESULTS.successful, base.message
    assert int(scaled.stats["steps"]) >= 2  # it moved from its start (it did not, in 1e-6)
    _assert_same_up_to_unit(base, scaled, unit)


@pytest.mark.parametrize("seed", [21, 22])
def test_separable_ls_is_the_same_in_any_output_unit(seed):
    _, v, y, start, unit = _case(seed)
    base = hbjax.separable_ls(start, (v, y), throw=False)
    scaled = hbjax.separable_ls(_in_unit(start, unit), (v, y * unit), throw=False)
    assert base.result == hbjax.RESULTS.successful, base.message
    _assert_same_up_to_unit(base, scaled, unit)


@pytest.mark.parametrize("unit", [1e-7, 1e7])
def test_fit_is_the_same_in_any_output_unit(unit):
    import jax

    sys, v, y, _, _ = _case(31)
    options = dict(na=sys["na"], nb=sys["nb"], m=sys["m"], key=jax.random.key(0), starts=8,
                   throw=False, progress=False)
    base = hbjax.fit((v, y), **options)
    scaled = hbjax.fit((v, y * unit), **options)
    assert base.result == hbjax.RESULTS.successful, base.message
    _assert_same_up_to_unit(base, scaled, unit)


def test_an_output_too_small_for_its_squares_is_refused_by_name():
    # Below 1e-100 the variances (squares) underflow to 0: a std of 0 would read as exact.
    _, v, y, start, _ = _case(11)
    with pytest.raises(ValueError, match=r"`recordings y` reaches a magnitude of only"):
        hbjax.refine(start, (v, y * 1e-120))
    with pytest.raises(ValueError, match=r"`y` reaches a magnitude of only"):
        hbjax.diagnose(start, v, y * 1e-120)
    # only an estimator's output: comparing a model with such a record forms no variances
    small = hbjax.Hammerstein(hbjax.Backlash(np.asarray(start.backlash.c1) * 1e-120,
                                             np.asarray(start.backlash.c2) * 1e-120), start.arx)
    assert np.isfinite(float(np.ravel(hbjax.compare(small, v, y * 1e-120).fit)[0]))
    # an output that is exactly zero is not a unit problem (it is refused elsewhere, or fits)
    assert hbjax.refine(start, (v, np.zeros_like(y)), throw=False).result is not None


@pytest.mark.parametrize("unit", [1e-7, 1e5])
def test_diagnose_names_the_same_findings_in_any_output_unit(unit):
    # The diagnosis's candidate solves take the residuals to the output's own unit: in
    # micro-units every candidate "converged" after 2-4 steps before, and a second,
    # spurious finding appeared beside the parameter mismatch.
    true = hbjax.default_system()
    nominal = hbjax.Hammerstein(true.backlash, hbjax.ARX([-1.1, 0.42], [1.0, 0.5]))
    rng = np.random.default_rng(5)
    v = np.repeat(rng.uniform(-8, 8, 150), 10)
    y = np.asarray(hbjax.simulate(true, v, 0.1 * rng.standard_normal(v.size)))

    def findings(k):
        scaled = hbjax.Hammerstein(nominal.backlash, hbjax.ARX(nominal.arx.a, nominal.arx.b * k))
        d = hbjax.diagnose(scaled, v, y * k, progress=False)
        return [f.effect for f in d.findings], d.candidates["parameter_mismatch"]["fit_sim"]

    (names, fit), (names_k, fit_k) = findings(1.0), findings(unit)
    assert names == names_k == ["parameter_mismatch"]
    assert fit_k == pytest.approx(fit, abs=0.01)
