"""The diagnosis's solvers pad records to a length bucket and mask the padding out: their
results equal the unpadded computation, and a new length inside a compiled bucket compiles
nothing new."""

import jax
import jax.numpy as jnp
import numpy as np

import hbjax
from hbjax._core.buckets import bucket_length
from hbjax._diagnose import candidates as cands
from hbjax._diagnose import solve
from hbjax._diagnose.effects import base_theta


def _record(n, seed):
    rng = np.random.default_rng(seed)
    model = hbjax.Hammerstein(hbjax.Backlash(c1=[-0.3, 1.0], c2=[0.3, 1.0]),
                              hbjax.ARX(a=[-0.7], b=[0.3]))
    v = np.repeat(rng.uniform(-2, 2, n // 10 + 1), 10)[:n] + 0.1 * np.sin(np.arange(n) / 7)
    truth = hbjax.Hammerstein(hbjax.Backlash(c1=[-0.35, 1.1], c2=[0.25, 1.0]),
                              hbjax.ARX(a=[-0.75], b=[0.28]))
    y = np.asarray(hbjax.simulate(truth, v, 0.02 * rng.standard_normal(n)))
    return model, v, y


def _setup(model, v, y):
    lay, theta = base_theta(model)
    K = 2 * lay.p_base
    S = jnp.asarray(cands.base_selection(lay, theta, K))[None]
    ints = jnp.asarray(cands._ints())[None]
    consts = jnp.asarray([float(np.max(np.abs(v))), float(np.mean(y)), float(np.std(y)), 0.05])
    return lay, theta[None], S, ints, consts


def test_padded_solvers_equal_the_unpadded_computation():
    n, burn = 300, 7
    model, v, y = _record(n, seed=0)
    assert bucket_length(n) > n  # the wrappers really pad
    lay, theta, S, ints, consts = _setup(model, v, y)
    vj, yj, window = jnp.asarray(v), jnp.asarray(y), jnp.asarray([burn, n])

    # fitted parameters, steps and convergence: the padded samples change nothing
    padded = solve.fit_batch(lay, theta, S, ints, consts, v, y, burn, 8, False)
    plain = solve._fit_batch(lay, theta, S, ints, consts, vj, yj, window, 8, False, "prediction")
    np.testing.assert_allclose(padded[0], plain[0], rtol=1e-9, atol=1e-12)
    assert int(padded[1][0]) == int(plain[1][0]) and bool(padded[2][0]) == bool(plain[2][0])
    moved = np.abs(np.asarray(padded[0] - theta))  # clip slots hold +-inf: nan here
    assert np.max(moved[np.isfinite(moved)]) > 1e-3  # the fit moved

    got = solve.sse_batch(lay, theta, ints, consts, v, y, burn)
    want = solve._sse_batch(lay, theta, ints, consts, vj, yj, window, "prediction")
    np.testing.assert_allclose(got, want, rtol=1e-10)

    evaluated = solve.evaluate_batch(lay, theta, ints, consts, v, y)
    unpadded = solve._evaluate_batch(lay, theta, ints, consts, vj, yj, "prediction")
    for a, b in zip(evaluated, unpadded):
        assert a.shape == (1, n)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-10)

    eps, J = solve.jacobian(lay, theta[0], S[0], ints[0], consts, v, y, burn)
    eps0, J0 = solve._jacobian(lay, theta[0], S[0], ints[0], consts, vj, yj, window,
                               "prediction")
    assert J.shape == (n, S.shape[2])
    np.testing.assert_allclose(eps, eps0, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(J, J0, rtol=1e-9, atol=1e-10)
    assert np.all(np.asarray(eps)[:burn] == 0) and np.all(np.asarray(J)[:burn] == 0)


def test_new_length_in_a_compiled_bucket_compiles_no_solver():
    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/jaxpr_trace_duration":
            compiled.append(str(kwargs.get("fun_name", "")))

    calls = [(_record(300, seed=1), 5), (_record(311, seed=2), 12)]
    assert bucket_length(300) == bucket_length(311)
    seen = []
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        # max_steps=9: a program no other test compiles, so the first call must trace it;
        # the second has another length and another burn-in (both runtime values)
        for (model, v, y), burn in calls:
            lay, theta, S, ints, consts = _setup(model, v, y)
            solve.fit_batch(lay, theta, S, ints, consts, v, y, burn, 9, False)
            seen.append(list(compiled))
            compiled.clear()
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert any("_fit_batch" in name for name in seen[0]), seen[0]  # the listener sees it
    assert not any("_fit_batch" in name for name in seen[1]), seen[1]
