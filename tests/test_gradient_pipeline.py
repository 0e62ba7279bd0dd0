"""Gradient pipeline (docs/refinement.md): an identified model inside a user's own
``jax.grad`` loop, tuning a backlash-inverse feed-forward so the output tracks a reference."""

import jax
import jax.numpy as jnp
import numpy as np

import hbjax


def test_identified_model_in_a_user_grad_loop():
    # 1. Identify the plant from an ordinary random-level experiment.
    plant = hbjax.default_system()
    rng = np.random.default_rng(0)
    n = 2000
    v_id = np.repeat(rng.uniform(-8, 8, n), rng.integers(1, 20, n))[:n]
    y_id = hbjax.simulate(plant, v_id, 0.1 * jax.random.normal(jax.random.PRNGKey(1), (n,)))
    model = hbjax.fit((v_id, y_id), na=2, nb=2, m=3, key=jax.random.PRNGKey(2), starts=8).model

    # 2. A reference to track and a feed-forward with a backlash-inverse term:
    #    v = g r(t+1) + d tanh(dr / eps), i.e. jump across the gap in the direction of motion.
    t = jnp.arange(400)
    r = 8.0 * jnp.sin(2 * jnp.pi * t / 200)
    r_next = jnp.concatenate([r[1:], r[-1:]])
    slope = jnp.tanh((r_next - r) / 0.05)

    def feedforward(params):
        gain, offset = params
        return gain * r_next + offset * slope

    def loss(params, m):
        y = m.simulate_trajectory(feedforward(params), jnp.zeros_like(r), 0.0)
        return jnp.mean((y[50:] - r[50:]) ** 2)

    grad = jax.jit(jax.value_and_grad(loss))
    params = jnp.array([0.2, 0.0])  # gain only: the backlash gap is not compensated
    first, _ = grad(params, model)
    scale = jnp.array([1e-4, 1e-2])  # per-parameter step sizes (the user's choice)
    for _ in range(300):
        value, g = grad(params, model)
        params = params - scale * g / (1.0 + jnp.abs(g) * scale)
    final, _ = grad(params, model)

    # The model's gradient agrees with finite differences.
    _, g = grad(params, model)
    h = 1e-6
    fd = [(loss(params + h * e, model) - loss(params - h * e, model)) / (2 * h)
          for e in jnp.eye(2)]
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-8)
    # Tuning on the identified model improves tracking of the real plant, and the
    # inverse term found is about the plant's half-gap seen at the input (1 / 0.9).
    assert float(final) < 0.05 * float(first)
    true_error = loss(params, plant)
    assert float(true_error) < 0.1 * float(loss(jnp.array([0.2, 0.0]), plant))
    assert 0.5 < float(params[1]) < 2.0
