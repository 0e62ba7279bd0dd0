"""The relaxed play operator (``smoothing=eps``): gradients flow inside the band, and it
tends to the exact operator as eps -> 0, in the dtype it is given."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax


def _record(n=600, seed=0):
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-8, 8, n // 6), 6) + 0.3 * rng.standard_normal(n)


def test_relaxed_tends_to_exact_as_eps_decreases(system):
    v = _record()
    exact = hbjax.play(system.backlash, v)
    errors = [float(jnp.max(jnp.abs(hbjax.play(system.backlash, v, smoothing=eps) - exact)))
              for eps in (0.1, 0.01, 0.001, 0.0001)]
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[0] > 1e-2 and errors[-1] < 1e-6
    y_exact = hbjax.simulate(system, v)
    y_relaxed = hbjax.simulate(system, v, smoothing=1e-4)
    assert float(jnp.max(jnp.abs(y_relaxed - y_exact))) < 1e-5
    np.testing.assert_array_equal(hbjax.play(system.backlash, v, smoothing=0.0), exact)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_gradient_inside_band_nonzero_only_when_relaxed(system, dtype):
    backlash = jax.tree_util.tree_map(lambda c: c.astype(dtype), system.backlash)
    # Start at rest, then inputs that keep the output strictly inside the band
    # (the default band has half-width about 1 around 0.9 v near v = 0).
    v = jnp.asarray([0.0, 0.3, -0.3, 0.5, 0.1], dtype)

    def loss(v, eps):
        return jnp.sum(hbjax.play(backlash, v, smoothing=eps) ** 2)

    g_exact = jax.grad(loss)(v, None)
    g_relaxed = jax.grad(loss)(v, 0.1)
    assert g_exact.dtype == dtype and g_relaxed.dtype == dtype
    np.testing.assert_array_equal(g_exact, 0.0)
    assert bool(jnp.all(jnp.abs(g_relaxed[1:]) > 1e-6)), g_relaxed
    # the same through the whole model
    model = jax.tree_util.tree_map(lambda c: c.astype(dtype), system)
    g_model = jax.grad(lambda v: jnp.sum(hbjax.simulate(model, v, smoothing=0.1) ** 2))(v)
    g_model_exact = jax.grad(lambda v: jnp.sum(hbjax.simulate(model, v) ** 2))(v)
    np.testing.assert_array_equal(g_model_exact, 0.0)
    assert bool(jnp.any(jnp.abs(g_model) > 1e-6))


def test_float32_stays_float32(system):
    model = jax.tree_util.tree_map(lambda c: c.astype(jnp.float32), system)
    v = jnp.asarray(_record(300), jnp.float32)
    y = hbjax.simulate(model, v, smoothing=0.05)
    u = hbjax.play(model.backlash, v, smoothing=0.05)
    assert y.dtype == jnp.float32 and u.dtype == jnp.float32
    assert bool(jnp.all(jnp.isfinite(y)))
    # relaxed float32 stays close to exact float64 at small eps
    ref = hbjax.play(system.backlash, np.asarray(v, np.float64))
    u_small = hbjax.play(model.backlash, v, smoothing=1e-4)
    assert float(jnp.max(jnp.abs(u_small - ref))) < 1e-3


def test_vmap_and_jit_over_models(system):
    models = jax.tree_util.tree_map(lambda c: jnp.stack([c, 1.1 * c]), system)
    v = jnp.asarray(_record(120))
    run = jax.jit(jax.vmap(lambda m: hbjax.simulate(m, v, smoothing=0.05)))
    y = run(models)
    assert y.shape == (2, 120)
    np.testing.assert_allclose(y[0], hbjax.simulate(system, v, smoothing=0.05), atol=1e-12)


def test_bad_smoothing_refused(system):
    v = np.ones(5)
    with pytest.raises(ValueError, match="smoothing"):
        hbjax.play(system.backlash, v, smoothing=-0.1)
    with pytest.raises(ValueError, match="smoothing"):
        hbjax.simulate(system, v, smoothing=np.nan)
    with pytest.raises(ValueError, match="smoothing"):
        hbjax.simulate(system, v, smoothing=[0.1, 0.2])
    with pytest.raises(TypeError, match="smoothing"):
        hbjax.play(system.backlash, v, smoothing="0.1")
