"""`fit` where the linear block has almost no static gain (``B(1)`` near 0).

Random systems whose output is a near-difference of the backlash output
(:func:`tests.generators.paper_class.random_differencing_system`, written apart from the
package): `B(1) = 1` is then a badly scaled normalisation and `fit` solves its starts a
second time in the paper's gauge. It must reach the optimum that refining from the true
system reaches, and report in ``B(1) = 1``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from tests.generators.paper_class import (
    INPUT_KINDS, random_differencing_system, random_input, simulate_numpy, to_hbjax,
)


def _record(seed):
    rng = np.random.default_rng(seed)
    sys_ = random_differencing_system(rng)
    v = random_input(rng, INPUT_KINDS[seed % len(INPUT_KINDS)], 1500, 1.5 * sys_["h_m"])
    y0, _ = simulate_numpy(sys_, v)
    y, _ = simulate_numpy(sys_, v, 0.01 * np.std(y0) * rng.standard_normal(v.size))
    return sys_, v, y


def test_fit_reaches_the_optimum_when_the_static_gain_vanishes():
    # Six random systems; the optimum is what refining from the true system reaches. Measured
    # at this commit: 5 of 6 with the second pass, 2 of 6 without it (one system, seed 4,
    # ends in a local minimum in both gauges: its 16 starts all stop 400-800 times above).
    reached = []
    for seed in range(3, 9):
        sys_, v, y = _record(seed)
        true = to_hbjax(sys_)
        b = np.asarray(true.arx.b)
        assert abs(b.sum()) < 1e-3 * np.abs(b).sum()  # the case this test is about
        options = dict(criterion="simulation", initial_state="estimate", throw=False)
        reference = hbjax.refine(hbjax.normalise_static_gain(true), (v, y), **options)
        assert reference.result == hbjax.RESULTS.successful, reference.message
        res = hbjax.fit((v, y), na=2, nb=2, m=sys_["m"], key=jax.random.key(seed),
                        starts=16, progress=False, **options)
        assert res.result == hbjax.RESULTS.successful, res.message
        assert res.gauge == "static_gain"
        assert float(np.sum(np.asarray(res.model.arx.b))) == pytest.approx(1.0, abs=1e-9)
        reached.append(float(res.stats["cost"]) <= 1.01 * float(reference.stats["cost"]))
    assert sum(reached) >= 5, reached


def test_a_stable_start_is_kept_as_it_is():
    # A lightly damped start (reflection coefficient -0.99965) must not be moved before the
    # solve: the search within stable models maps it to its own free parameters.
    from hbjax._identify.stable import a_from_free, free_from_a

    for a in ([-1.992, 0.9927], [-1.9999, 0.99995], [0.5], [-0.9999999]):
        a = np.asarray(a)
        np.testing.assert_allclose(np.asarray(a_from_free(free_from_a(a))), a, rtol=1e-9)
    # an unstable start is projected onto the stable models
    assert np.all(np.abs(np.roots(np.r_[1.0, np.asarray(a_from_free(free_from_a(
        np.asarray([-2.1, 1.1]))))])) < 1)


@pytest.mark.parametrize("seed", [3, 5, 7])
def test_standard_errors_where_the_static_gain_vanishes(seed):
    """The reported covariance is the Gauss-Newton one, computed here independently: the
    one-step errors' Jacobian in ``theta`` (``b_1 = 1 - b_2 - ...`` eliminated), its
    columns equilibrated, inverted in full. Before, the solve's ``J^T J`` was
    pseudo-inverted raw, whose relative cut-off (~1e-15) dropped the directions where
    ``b`` ~ 1e3-1e4 and reported ``std(b)`` of 1e-12-1e-9 against 12-35000."""
    sys_, v, y = _record(seed)
    res = hbjax.refine(hbjax.normalise_static_gain(to_hbjax(sys_)), (v, y),
                       initial_state="estimate", restarts=0, throw=False)
    assert res.result == hbjax.RESULTS.successful, res.message
    na, nb = res.model.arx.na, res.model.arx.nb
    theta = np.asarray(hbjax.flatten_params(res.model))

    def errors(free):  # the records' first max(na, nb) samples reach before them: left out
        b_first = 1.0 - jnp.sum(free[na:na + nb - 1], keepdims=True)
        model = hbjax.unflatten_params(res.model, jnp.concatenate([free[:na], b_first, free[na:]]))
        return (jnp.asarray(y) - hbjax.predict(model, jnp.asarray(v), jnp.asarray(y)))[max(na, nb):]

    free = jnp.asarray(np.concatenate([theta[:na], theta[na + 1:]]))
    jac, e = np.asarray(jax.jacfwd(errors)(free)), np.asarray(errors(free))
    scale = np.linalg.norm(jac, axis=0)
    cov = (e @ e / (e.size - free.size)) * np.linalg.inv(
        (jac / scale).T @ (jac / scale)) / np.outer(scale, scale)
    reported = np.sqrt(np.diag(np.asarray(res.covariance)))
    expected = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(reported[na + 1:], expected[na:], rtol=0.02)
    np.testing.assert_allclose(reported[:na], expected[:na], rtol=0.02)
    assert np.abs(np.asarray(res.model.arx.b)).max() > 100  # the case this test is about
