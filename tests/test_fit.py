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
