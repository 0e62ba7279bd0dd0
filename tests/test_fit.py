"""Multi-start identification from ordinary data (issue 3) and the Cramér–Rao bound."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax


def random_levels(rng, n, amplitude=8.0, max_hold=20):
    """Random levels in [-amplitude, amplitude] held for random durations (1..max_hold)."""
    levels = rng.uniform(-amplitude, amplitude, n)
    return np.repeat(levels, rng.integers(1, max_hold, n))[:n]


@pytest.fixture(scope="module")
def ordinary():
    system = hbjax.default_system()
    rng = np.random.default_rng(4)
    n, sigma = 3000, 0.3
    v = random_levels(rng, n)
    y = np.asarray(hbjax.simulate(system, v, sigma * jax.random.normal(jax.random.PRNGKey(8), (n,))))
    return system, v, y, sigma


def test_fit_recovers_default_system_from_random_levels(ordinary):
    system, v, y, sigma = ordinary
    res = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.PRNGKey(0), starts=16)
    truth = np.asarray(hbjax.flatten_params(hbjax.normalise_static_gain(system)))
    est = np.asarray(hbjax.flatten_params(res.model))
    assert res.message == "success"
    assert np.all(np.abs(est - truth) < 5 * np.asarray(res.std))
    assert np.max(np.abs(est - truth)) < 0.05
    assert float(jnp.sum(res.model.arx.b)) == pytest.approx(1.0)
    # P1 is the rising branch: the lower one for this increasing backlash
    assert float(res.model.backlash.p1(0.0)) < float(res.model.backlash.p2(0.0))
    assert res.starts_costs.shape == (16,) and res.starts_params.shape == (16, 10)
    assert 0 < float(res.hit_rate) <= 1
    assert float(res.stats["cost"]) == pytest.approx(float(jnp.min(res.starts_costs)))
    assert float(res.noise_std) == pytest.approx(sigma, rel=0.1)


def test_fit_bad_input(ordinary):
    _, v, y, _ = ordinary
    with pytest.raises(TypeError, match="key"):
        hbjax.fit((v, y), na=2, nb=2, m=3, key=0)
    with pytest.raises(ValueError, match="nb"):
        hbjax.fit((v, y), na=2, nb=0, m=3, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="equal lengths"):
        hbjax.fit((v, y[:10]), na=2, nb=2, m=3, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="samples"):
        hbjax.fit((v[:12], y[:12]), na=2, nb=2, m=3, key=jax.random.PRNGKey(0))


def test_normalise_static_gain(system):
    model = hbjax.normalise_static_gain(system)
    assert float(jnp.sum(model.arx.b)) == pytest.approx(1.0)
    v = np.linspace(-8, 8, 200)
    np.testing.assert_allclose(hbjax.simulate(model, v), hbjax.simulate(system, v), atol=1e-12)
    zero = hbjax.Hammerstein(system.backlash, hbjax.ARX(system.arx.a, [1.0, -1.0]))
    with pytest.raises(ValueError, match="B\\(1\\)"):
        hbjax.normalise_static_gain(zero)


def test_crlb_properties_and_bad_input(ordinary):
    system, v, y, sigma = ordinary
    model = hbjax.normalise_static_gain(system)
    bound = hbjax.crlb(model, (v, y), noise_std=sigma)
    f, cov, g = (np.asarray(x) for x in (bound.fisher, bound.covariance, bound.constraint))
    np.testing.assert_allclose(f, f.T, atol=1e-9 * np.abs(f).max())
    assert np.linalg.eigvalsh(f).min() > -1e-9 * np.abs(f).max()
    np.testing.assert_allclose(cov @ g, 0.0, atol=1e-14)  # no variance along the constraint
    assert np.all(np.asarray(bound.std) > 0)
    # the bound scales with sigma^2
    half = hbjax.crlb(model, (v, y), noise_std=sigma / 2)
    np.testing.assert_allclose(half.covariance, cov / 4, rtol=1e-10, atol=1e-20)
    # the asymptotic covariance of the prediction-error estimate is the bound
    res = hbjax.refine(model, (v, y))
    np.testing.assert_allclose(np.asarray(res.std), np.asarray(bound.std), rtol=0.1)
    sim = hbjax.crlb(model, (v, y), noise_std=sigma, criterion="simulation")
    assert sim.fisher.shape == (10, 10)
    with pytest.raises(ValueError, match="not normalised"):
        hbjax.crlb(system, (v, y), noise_std=sigma)
    with pytest.raises(ValueError, match="not normalised"):
        hbjax.crlb(model, (v, y), noise_std=sigma, h_m=4.0)
    with pytest.raises(ValueError, match="noise_std"):
        hbjax.crlb(model, (v, y), noise_std=0.0)


def _poles(a):
    return np.abs(np.roots(np.concatenate([[1.0], np.asarray(a)])))


def test_fit_searches_within_stable_models(system):
    """Data from a linear block with a pole at 1.003: refinement without the constraint
    converges to an unstable model (refused); every start of `fit` stays stable."""
    p1, p2 = 1.003, 0.5
    unstable = hbjax.Hammerstein(system.backlash, hbjax.ARX([-(p1 + p2), p1 * p2], [1.0, 0.5]))
    rng = np.random.default_rng(1)
    n = 400
    v = random_levels(rng, n)
    y = np.asarray(hbjax.simulate(unstable, v, 0.05 * rng.normal(size=n)))
    free = hbjax.refine(hbjax.normalise_static_gain(unstable), (v, y), throw=False)
    assert free.result == hbjax.RESULTS.unstable and not bool(free.stable)
    res = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.PRNGKey(0), starts=4, throw=False,
                    progress=False)
    assert res.result != hbjax.RESULTS.unstable and bool(res.stable)
    assert _poles(res.model.arx.a).max() < 1.0
    for params in np.asarray(res.starts_params):
        assert _poles(params[:2]).max() < 1.0


@pytest.fixture(scope="module")
def mid_motion():
    """A record cut from the middle of a run: it does not start at rest (y(0) far from 0)."""
    system = hbjax.default_system()
    rng = np.random.default_rng(7)
    n, skip = 1200, 300
    v = random_levels(rng, n + skip)
    xi = 0.1 * jax.random.normal(jax.random.PRNGKey(3), (n + skip,))
    y = np.asarray(hbjax.simulate(system, v, xi))[skip:]
    return system, v[skip:], y


def test_fit_and_refine_estimate_the_initial_state(mid_motion):
    system, v, y = mid_motion
    assert abs(y[0]) > 1.0
    truth = np.asarray(hbjax.flatten_params(hbjax.normalise_static_gain(system)))
    res = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.PRNGKey(0), starts=4,
                    progress=False)
    assert res.initial_state == "estimate"
    est = np.asarray(hbjax.flatten_params(res.model))
    assert np.all(np.abs(est - truth) < 5 * np.asarray(res.std))
    # the reported free-run fit starts from the estimated initial state, as compare's
    cmp = hbjax.compare(res.model, v, y, initial_state="estimate")
    assert float(res.sim_fit[0]) == pytest.approx(cmp.fit, abs=1e-6)
    zero = hbjax.compare(res.model, v, y, initial_state="zero")
    assert cmp.fit > zero.fit
    # refine: the prediction errors of the first max(na, nb) samples are left out
    start = hbjax.normalise_static_gain(system)
    r_est = hbjax.refine(start, (v, y), initial_state="estimate")
    r_zero = hbjax.refine(start, (v, y), throw=False)
    assert r_zero.initial_state == "zero" and r_est.initial_state == "estimate"
    err_est = np.abs(np.asarray(hbjax.flatten_params(r_est.model)) - truth)
    err_zero = np.abs(np.asarray(hbjax.flatten_params(r_zero.model)) - truth)
    assert np.all(err_est < 5 * np.asarray(r_est.std))
    assert np.all(err_zero < 5 * np.asarray(r_zero.std))  # (two samples' worth of bias)


def test_simulation_criterion_estimates_the_initial_state(system):
    """Output-error refinement on a record that does not start at rest (white output
    noise: the simulation criterion is the maximum-likelihood one)."""
    rng = np.random.default_rng(11)
    n, skip = 1000, 250
    v = random_levels(rng, n + skip)
    y = np.asarray(hbjax.simulate(system, v))[skip:] + 0.1 * rng.normal(size=n)
    v = v[skip:]
    truth = np.asarray(hbjax.flatten_params(hbjax.normalise_static_gain(system)))
    res = hbjax.refine(hbjax.normalise_static_gain(system), (v, y), criterion="simulation",
                       initial_state="estimate")
    est = np.asarray(hbjax.flatten_params(res.model))
    assert np.all(np.abs(est - truth) < 5 * np.asarray(res.std))
    # free run from the estimated initial state (play state included): the noise level
    assert hbjax.compare(res.model, v, y).rmse == pytest.approx(0.1, rel=0.15)
    zero = hbjax.refine(hbjax.normalise_static_gain(system), (v, y), criterion="simulation",
                        throw=False)
    # A start at rest leaves the unknown past in the residuals: a clearly worse optimum.
    assert float(zero.stats["cost"]) > 1.1 * float(res.stats["cost"])


def test_initial_state_bad_input(ordinary):
    _, v, y, _ = ordinary
    with pytest.raises(ValueError, match="`initial_state` must be one of"):
        hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.PRNGKey(0), initial_state="e")
    with pytest.raises(ValueError, match="`initial_state` must be one of"):
        hbjax.refine(hbjax.default_system(), (v, y), h_m=4.0, initial_state=None)


def test_compare_estimates_the_initial_state_of_a_model_extension(system):
    """A diagnosis effect (output saturation around the nominal model) on a record cut
    from the middle of a run: the estimated start removes the start-up transient."""
    effect = hbjax.EFFECTS["output_saturation"](system, -100.0, 3.0)
    rng = np.random.default_rng(0)
    v = np.repeat(rng.uniform(-8, 8, 100), 20)
    y = np.asarray(hbjax.simulate(effect, v))
    v, y = v[300:], y[300:]
    zero = hbjax.compare(effect, v, y, initial_state="zero")
    est = hbjax.compare(effect, v, y, initial_state="estimate")
    assert est.fit > 99.0 and est.fit > zero.fit + 1.0
    assert est.initial_states[0].y0.shape == (2,)
    with pytest.raises(TypeError, match="initial_state='zero'"):
        hbjax.compare(object.__new__(type("Bare", (hbjax.AbstractModel,), {
            "simulate_trajectory": lambda *a: None, "predict_trajectory": lambda *a: None})),
            v, y)
