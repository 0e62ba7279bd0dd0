"""Semantics of the model, simulator and signals (NOTES.md conventions)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import reference_simulate

import hbjax


def test_play_hand_computed_turning_points():
    # P1(v) = v - 1 (rising branch), P2(v) = v + 1 (falling): a backlash of half-width 1.
    bl = hbjax.Backlash([-1.0, 1.0], [1.0, 1.0])
    v = np.array([0.0, 2.0, 3.0, 2.5, 1.0, 0.5, -1.0, 0.0, 0.5])
    # u(-1) = 0: band [v-1, v+1]; rise to 3 drags u to 2; falling to 1.0 keeps 2 until
    # v + 1 < 2; then u follows v + 1; turning up at -1 leaves u = 0 inside the band.
    expected = [0.0, 1.0, 2.0, 2.0, 2.0, 1.5, 0.0, 0.0, 0.0]
    np.testing.assert_allclose(hbjax.play(bl, v), expected, atol=0)
    # The initial state is u(-1) = u0.
    np.testing.assert_allclose(hbjax.play(bl, [0.0], u0=0.7), [0.7])
    np.testing.assert_allclose(hbjax.play(bl, [0.0], u0=5.0), [1.0])


def test_arx_recursion_hand_computed_zero_initial_conditions():
    # u = play output; choose a backlash whose band collapses to u = v (P1 = P2 = v).
    model = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [0.0, 1.0]), hbjax.ARX([-0.5], [2.0, 1.0]))
    v = np.array([1.0, 0.0, 0.0, 0.0])
    xi = np.array([0.1, 0.0, 0.0, 0.0])
    # y(0) = xi(0); y(1) = 0.5 y(0) + 2 u(0) + 0; y(2) = 0.5 y(1) + 2 u(1) + 1 u(0); ...
    y0 = 0.1
    y1 = 0.5 * y0 + 2.0
    y2 = 0.5 * y1 + 0.0 + 1.0
    y3 = 0.5 * y2
    np.testing.assert_allclose(hbjax.simulate(model, v, xi), [y0, y1, y2, y3], rtol=1e-15)


def test_signals_first_periods():
    d = hbjax.GiriDesign(2, 3, 4.0)
    np.testing.assert_array_equal(d.constant_input(4), [0.0, 4.0, 4.0, 4.0])
    v2 = d.binary_input(16)
    expected = np.full(16, 4.0)
    expected[[4, 12]] = -4.0  # t mod 8 == 4
    np.testing.assert_array_equal(v2, expected)
    np.testing.assert_array_equal(d.binary_internal(16), (expected < 0).astype(float))
    v3 = d.staircase_input(18)  # one period 2m(n+1) = 18, plateaus of n+1 = 3
    levels = [4.0, 4.0 + 4 / 3, 4.0 + 8 / 3, -4.0, -4.0 - 4 / 3, -4.0 - 8 / 3]
    np.testing.assert_allclose(v3, np.repeat(levels, 3), rtol=1e-15)
    t, j = d.estimation_instants(20)
    np.testing.assert_array_equal(t, [2, 5, 8, 11, 14, 17])
    np.testing.assert_array_equal(j, [0, 1, 2, 3, 4, 5])


def _random_system(rng, na, nb, m):
    c = rng.normal(size=m) * 0.3
    c1 = c.copy()
    c1[0] -= 1.0
    c2 = c + rng.normal(size=m) * 0.05
    c2[0] += 1.0
    # Real poles inside the unit circle (assumption A3).
    a = np.atleast_1d(np.poly(rng.uniform(-0.8, 0.8, na)))[1:]
    return hbjax.Hammerstein(hbjax.Backlash(c1, c2), hbjax.ARX(a, rng.normal(size=nb)))


@pytest.mark.parametrize("na, nb, m, u0", [(1, 1, 1, 0.0), (2, 2, 3, 0.0), (3, 1, 2, 0.4), (0, 3, 4, -0.2), (4, 4, 5, 1.0)])
def test_simulate_matches_independent_numpy_loop(na, nb, m, u0):
    rng = np.random.default_rng(na * 100 + nb * 10 + m)
    model = _random_system(rng, na, nb, m)
    v = rng.uniform(-3, 3, 400)
    xi = rng.normal(size=400) * 0.1
    y_ref, u_ref = reference_simulate(model.backlash.c1, model.backlash.c2, model.arx.a, model.arx.b, v, xi, u0)
    np.testing.assert_allclose(hbjax.play(model.backlash, v, u0=u0), u_ref, atol=1e-12)
    np.testing.assert_allclose(hbjax.simulate(model, v, xi, u0=u0), y_ref, atol=1e-10)
    # The one-step predictor leaves exactly the equation error.
    y_hat = hbjax.predict(model, v, y_ref, u0=u0)
    np.testing.assert_allclose(y_ref - y_hat, xi, atol=1e-10)


def test_jit_and_time_major_vmap(system):
    rng = np.random.default_rng(0)
    V = rng.uniform(-8, 8, (300, 5))
    X = rng.normal(size=(300, 5))
    batched = jax.jit(jax.vmap(hbjax.simulate, in_axes=(None, 1, 1), out_axes=1))(system, V, X)
    assert batched.shape == (300, 5)
    for b in range(5):
        np.testing.assert_allclose(batched[:, b], hbjax.simulate(system, V[:, b], X[:, b]), atol=1e-12)
    u = jax.vmap(hbjax.play, in_axes=(None, 1), out_axes=1)(system.backlash, V)
    np.testing.assert_allclose(u[:, 2], hbjax.play(system.backlash, V[:, 2]), atol=0)
    y_hat = jax.jit(hbjax.predict)(system, V[:, 0], batched[:, 0])
    np.testing.assert_allclose(batched[:, 0] - y_hat, X[:, 0], atol=1e-10)


def _fd_check(f, model, direction, eps=1e-6):
    grad = jax.grad(f)(model)
    leaves = jax.tree_util.tree_leaves(grad)
    dirs = jax.tree_util.tree_leaves(direction)
    analytic = sum(float(jnp.vdot(g, d)) for g, d in zip(leaves, dirs))
    plus = jax.tree_util.tree_map(lambda p, d: p + eps * d, model, direction)
    minus = jax.tree_util.tree_map(lambda p, d: p - eps * d, model, direction)
    numeric = (f(plus) - f(minus)) / (2 * eps)
    return analytic, float(numeric)


def test_grad_of_simulate_and_play_matches_finite_differences(system):
    rng = np.random.default_rng(3)
    # Smooth random-level input: the play operator is differentiable almost everywhere.
    v = np.repeat(rng.uniform(-8, 8, 40), 5)
    xi = rng.normal(size=v.size) * 0.1
    target = np.asarray(hbjax.simulate(system, v, xi)) + rng.normal(size=v.size)
    direction = jax.tree_util.tree_map(lambda p: jnp.asarray(rng.normal(size=p.shape)), system)

    def loss(model):
        return jnp.sum((hbjax.simulate(model, v, xi) - target) ** 2)

    analytic, numeric = _fd_check(loss, system, direction)
    assert analytic == pytest.approx(numeric, rel=1e-5)

    def loss_play(model):
        return jnp.sum(jnp.sin(hbjax.play(model.backlash, v)))

    analytic, numeric = _fd_check(loss_play, system, direction)
    assert analytic == pytest.approx(numeric, rel=1e-5)
    # Under jit too.
    g1 = jax.grad(loss)(system)
    g2 = jax.jit(jax.grad(loss))(system)
    np.testing.assert_allclose(hbjax.flatten_params(g1), hbjax.flatten_params(g2), rtol=1e-10)


def test_normalise_makes_gap_one_and_preserves_input_output(system, design):
    norm = hbjax.normalise(system, design.h_m)
    m1 = float(norm.backlash.p1(design.h_m))
    m2 = float(norm.backlash.p2(-design.h_m))
    assert m2 - m1 == pytest.approx(1.0, abs=1e-14)
    rng = np.random.default_rng(1)
    v = rng.uniform(-8, 8, 200)
    np.testing.assert_allclose(hbjax.simulate(norm, v), hbjax.simulate(system, v), atol=1e-10)


def test_params_round_trip(system):
    theta = hbjax.flatten_params(system)
    assert hbjax.param_names(system)[:3] == ["a1", "a2", "b1"]
    back = hbjax.unflatten_params(system, theta)
    np.testing.assert_array_equal(hbjax.flatten_params(back), theta)
    with pytest.raises(ValueError, match="theta"):
        hbjax.unflatten_params(system, theta[:-1])


def test_simulate_bad_inputs(system, design):
    v = np.linspace(-1, 1, 50)
    with pytest.raises(ValueError, match="records must have equal lengths: `v` has 50, `noise` has 49"):
        hbjax.simulate(system, v, np.zeros(49))
    with pytest.raises(ValueError, match="`v` must be a 1-D array"):
        hbjax.simulate(system, v.reshape(5, 10))
    with pytest.raises(ValueError, match="`v` must have at least 1 samples"):
        hbjax.simulate(system, np.array([]))
    bad = v.copy()
    bad[3] = np.inf
    with pytest.raises(ValueError, match="`v` contains NaN or inf.*index 3"):
        hbjax.simulate(system, bad)
    with pytest.raises(TypeError, match="`model` must be an hbjax.AbstractModel"):
        hbjax.simulate(system.arx, v)
    with pytest.raises(TypeError, match="`v` must be a numeric array"):
        hbjax.simulate(system, ["a", "b"])
    with pytest.raises(ValueError, match="`c1` and `c2` must have the same length"):
        hbjax.Backlash([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="`b` must hold at least one coefficient"):
        hbjax.ARX([0.5], [])
    with pytest.raises(ValueError, match="`y` contains NaN"):
        hbjax.predict(system, v, np.full(50, np.nan))
    with pytest.raises(ValueError, match="design expects na = nb = n = 2 and m = 3"):
        design.check_model(hbjax.Hammerstein(system.backlash, hbjax.ARX([0.1], [1.0])))
    # Integer and float32 inputs are promoted to float64.
    y32 = hbjax.simulate(system, v.astype(np.float32))
    assert y32.dtype == jnp.float64
    assert hbjax.simulate(system, np.arange(5)).dtype == jnp.float64


def test_non_finite_input_under_jit_raises_with_message(system):
    v = jnp.array([0.0, 1.0, jnp.nan, 2.0])
    with pytest.raises(Exception, match="`v` contains NaN or inf"):
        jax.jit(hbjax.simulate)(system, v).block_until_ready()
    with pytest.raises(Exception, match="`v` contains NaN or inf"):
        jax.vmap(hbjax.simulate, in_axes=(None, 1))(system, jnp.stack([v, v], 1)).block_until_ready()


@pytest.mark.parametrize("smoothing", [None, 0.1])
def test_identical_branches_differentiate_as_their_static_map(smoothing):
    """With ``P1 = P2 = P`` the play operator is the static map ``u(t) = P(v(t))``, whatever
    the past: its Jacobian in ``v`` is ``diag(P'(v))``, also where the input holds (a tie
    of ``u(t-1)`` with the band's edge, where a half-and-half split of the derivative was
    wrong); through ``simulate`` the gradient is the ARX impulse response times ``P'``.
    Random cubic branches and inputs that hold for runs of samples."""
    rng = np.random.default_rng(7)
    for _ in range(4):
        c = rng.normal(size=4)
        bl = hbjax.Backlash(c, c)
        v = jnp.asarray(np.repeat(rng.uniform(-2, 2, size=8), rng.integers(1, 4, size=8)))
        dp = np.polyval(np.polyder(c[::-1]), np.asarray(v))
        jac = np.asarray(jax.jacfwd(lambda x: hbjax.play(bl, x, smoothing=smoothing))(v))
        np.testing.assert_allclose(jac, np.diag(dp), atol=1e-12)
        np.testing.assert_allclose(np.asarray(jax.jacrev(
            lambda x: hbjax.play(bl, x, smoothing=smoothing))(v)), np.diag(dp), atol=1e-12)
        model = hbjax.Hammerstein(bl, hbjax.ARX(a=[-0.5], b=[1.0]))
        grad = np.asarray(jax.grad(lambda x: hbjax.simulate(model, x)[-1])(v))
        T = v.shape[0]
        impulse = np.array([0.5 ** (T - 2 - s) if s <= T - 2 else 0.0 for s in range(T)])
        np.testing.assert_allclose(grad, impulse * dp, atol=1e-12)
