"""Compiled fitting engine of the diagnosis: every candidate extension is fitted jointly
with the base parameters by Levenberg-Marquardt (``optimistix.least_squares``) on the
prediction error of the extended simulator, all candidates of a batch in one compiled
``jax.lax.map``.

A candidate is data: a start ``theta0`` (full extended vector), the discrete values
``ints = [delay, change time]`` and a selection matrix ``S`` (columns = the free
parameters, scaled); the fitted vector is ``theta0 + S delta``. So one compiled solver
serves every effect of a base structure, and compiled code is cached across calls by
``eqx.filter_jit``.

Records are padded to a length bucket (:mod:`hbjax._core.buckets`) by the functions
below, which callers use with the recorded signals: every error is causal, so the
recorded samples are computed as without the padding, and the criterion's window
``[burn, n)`` is a runtime value that masks the padded samples (and the start-up burn-in)
out of every sum. One compiled program therefore serves every record length of a bucket
and every burn-in, where each new length (about 30 s of compilation on a 2-core CPU)
used to cost a fresh one.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._core.buckets import bucket_length, padded
from .._identify.lm import levenberg_marquardt
from .effect_base import base_model, term_error
from .kernel import Layout, fast_jacobian, fast_prediction_error, play_gather, prediction_error


def _bucketed(v, y, burn: int = 0):
    """``(v, y, window)``: the record padded to its length bucket and the criterion's
    window ``[burn, n)`` as an integer array (a runtime value of the compiled solvers)."""
    n = int(np.shape(v)[0])
    size = bucket_length(n)
    return (jnp.asarray(padded(v, size, hold=True)), jnp.asarray(padded(y, size, hold=True)),
            jnp.asarray([int(burn), n]))


def _in_window(T, window):
    t = jnp.arange(T)
    return (t >= window[0]) & (t < window[1])


def _masked(e, window):
    """Errors outside the criterion's window set to zero; a diverging candidate's (an
    unstable linear block) large but finite, so it cannot poison a batch."""
    e = jnp.where(_in_window(e.shape[0], window), e, 0.0)
    return jnp.where(jnp.isfinite(e), e, 1e6)


def _masked_eps(lay, theta, ints, consts, v, y, window, output_static=True,
                criterion="prediction"):
    return _masked(fast_prediction_error(lay, theta, ints, consts, v, y,
                                         output_static=output_static, criterion=criterion),
                   window)


def _masked_jacobian(lay, theta, S, ints, consts, v, y, window, output_static, criterion):
    """Jacobian of :func:`_masked_eps` in the directions ``S``: written out by hand where
    the output map is the identity, forward-mode autodiff otherwise."""
    if output_static:
        J = jax.jacfwd(lambda d: _masked_eps(lay, theta + S @ d, ints, consts, v, y, window,
                                             True, criterion))(jnp.zeros(S.shape[1]))
    else:
        J = fast_jacobian(lay, theta, ints, consts, v, y, criterion=criterion) @ S
        J = jnp.where(_in_window(y.shape[0], window)[:, None], J, 0.0)
    return jnp.where(jnp.isfinite(J), J, 0.0)


def fit_batch(lay: Layout, theta0, S, ints, consts, v, y, burn: int, max_steps: int,
              output_static: bool, criterion: str = "prediction"):
    """Levenberg-Marquardt from each ``theta0[i]`` over the columns of ``S[i]``.

    Shapes: ``theta0 (B, P)``, ``S (B, P, K)``, ``ints (B, 2)``; ``v, y`` the fitting
    segment, samples from ``burn`` on in the criterion. Returns ``(theta (B, P), steps
    (B,), converged (B,))``.
    """
    return _fit_batch(lay, theta0, S, ints, consts, *_bucketed(v, y, burn), max_steps,
                      output_static, criterion)


@eqx.filter_jit
def _fit_batch(lay, theta0, S, ints, consts, v, y, window, max_steps, output_static, criterion):
    def one(th0, s, it):
        def eps(delta):
            return _masked_eps(lay, th0 + s @ delta, it, consts, v, y, window, output_static,
                               criterion)

        def jac(delta):
            return _masked_jacobian(lay, th0 + s @ delta, s, it, consts, v, y, window,
                                    output_static, criterion)

        value, steps, ok = _least_squares(eps, jac, s.shape[1], max_steps, _unit(y))
        return th0 + s @ value, steps, ok

    # One candidate after the other: under ``vmap`` every candidate would take as many
    # Levenberg-Marquardt steps as the slowest one and the batch's Jacobians would not stay
    # in cache (benchmarks/against_earlier.py's diagnose: 942 -> 736 ms on the 2-core CPU).
    return jax.lax.map(lambda args: one(*args), (theta0, S, ints))


def _unit(y):
    """For an output whose largest magnitude is below 0.5, the power of two ``2^e`` with
    ``max |y| / 2^e`` in ``[0.5, 1)``; otherwise 1 (also for an output that is all 0 or not
    finite). The residuals are solved in it (exact: a power of two). The solver's absolute
    tolerance on the cost's change is met at once where the cost is tiny: for an output
    near 1e-6 every candidate "converged" after 2-4 steps and the findings changed with
    the output's unit. A large output only makes that tolerance strict (more steps, same
    optimum: the same findings at 1e4 and 1e7), and outputs from 0.5 up keep the solves
    the diagnosis was validated with bit for bit."""
    peak = jnp.max(jnp.abs(y))
    _, exponent = jnp.frexp(peak)
    usable = jnp.isfinite(peak) & (peak > 0) & (exponent <= 0)
    return jnp.where(usable, jnp.ldexp(jnp.ones_like(peak), exponent), 1.0)


def _least_squares(eps, jac, n: int, max_steps: int, unit):
    """Levenberg-Marquardt (the package's one set-up, :mod:`hbjax._identify.lm`) on
    ``eps(delta) / unit`` from ``delta = 0`` with the hand-written Jacobian ``jac(delta)``;
    returns ``(delta, steps, converged)``. Without the unit, an output near 1e-6 met the
    absolute tolerance on the cost's change at once: every candidate "converged" after 2-4
    steps and the findings changed with the output's unit."""
    sol = levenberg_marquardt(lambda d, _: eps(d) / unit, jnp.zeros(n), max_steps=max_steps,
                              rtol=1e-5, atol=1e-8, jac=lambda d, _: jac(d) / unit)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def sse_batch(lay: Layout, theta, ints, consts, v, y, burn: int, criterion: str = "prediction"):
    """Sum of squared prediction errors (samples from ``burn`` on) for a batch of extended
    parameter vectors."""
    return _sse_batch(lay, theta, ints, consts, *_bucketed(v, y, burn), criterion)


@eqx.filter_jit
def _sse_batch(lay, theta, ints, consts, v, y, window, criterion):
    return jax.vmap(lambda th, it: jnp.sum(
        _masked_eps(lay, th, it, consts, v, y, window, True, criterion) ** 2))(theta, ints)


def evaluate_batch(lay: Layout, theta, ints, consts, v, y, criterion: str = "prediction"):
    """``(fast eps, exact eps, y_sim, u_used)`` over the whole record for a batch of
    candidates (the exact ones from the simulator's scan), each ``(B, T)``."""
    T = int(np.shape(v)[0])
    vp, yp, _ = _bucketed(v, y)
    return tuple(a[:, :T] for a in _evaluate_batch(lay, theta, ints, consts, vp, yp, criterion))


@eqx.filter_jit
def _evaluate_batch(lay, theta, ints, consts, v, y, criterion):
    def one(th, it):
        return (fast_prediction_error(lay, th, it, consts, v, y, criterion=criterion),
                *prediction_error(lay, th, it, consts, v, y))

    return jax.vmap(one)(theta, ints)


def jacobian(lay: Layout, theta, S, ints, consts, v, y, burn: int, criterion: str = "prediction"):
    """``(eps, d eps / d delta)`` at ``delta = 0`` (for the change-point scan); rows
    before ``burn`` are zero."""
    T = int(np.shape(v)[0])
    eps, J = _jacobian(lay, theta, S, ints, consts, *_bucketed(v, y, burn), criterion)
    return eps[:T], J[:T]


@eqx.filter_jit
def _jacobian(lay, theta, S, ints, consts, v, y, window, criterion):
    eps = _masked_eps(lay, theta, ints, consts, v, y, window, False, criterion)
    return eps, _masked_jacobian(lay, theta, S, ints, consts, v, y, window, False, criterion)


# --- the generic path: effects that are not slots of the kernel ------------------------


def fit_terms(cls, lay: Layout, theta0, S, params0, scales, consts, v, y, burn: int,
              max_steps: int, criterion: str = "prediction"):
    """Levenberg-Marquardt of a generic effect ``cls`` (:func:`term_error`) jointly with
    the base parameters (columns of ``S``), Jacobian by ``jax.jacfwd``. Returns
    ``(theta, params, steps, converged)``."""
    return _fit_terms(cls, lay, theta0, S, params0, scales, consts, *_bucketed(v, y, burn),
                      max_steps, criterion)


@eqx.filter_jit
def _fit_terms(cls, lay, theta0, S, params0, scales, consts, v, y, window, max_steps,
               criterion):
    K = S.shape[1]

    def split(delta):
        return theta0 + S @ delta[:K], params0 + scales * delta[K:]

    def eps(delta):
        return _masked(term_error(cls, lay, *split(delta), consts, v, y, criterion), window)

    def jac(delta):
        J = jax.jacfwd(eps)(delta)
        return jnp.where(jnp.isfinite(J), J, 0.0)

    value, steps, ok = _least_squares(eps, jac, K + params0.shape[0], max_steps, _unit(y))
    theta, params = split(value)
    return theta, params, steps, ok


def sse_terms(cls, lay: Layout, theta, params, consts, v, y, burn: int,
              criterion: str = "prediction"):
    """Sum of squared errors (samples from ``burn`` on) of a generic effect for a batch of
    parameter starts."""
    return _sse_terms(cls, lay, theta, params, consts, *_bucketed(v, y, burn), criterion)


@eqx.filter_jit
def _sse_terms(cls, lay, theta, params, consts, v, y, window, criterion):
    return jax.vmap(lambda p: jnp.sum(_masked(
        term_error(cls, lay, theta, p, consts, v, y, criterion), window) ** 2))(params)


def evaluate_terms(cls, lay: Layout, theta, params, consts, v, y, criterion="prediction"):
    """``(fitting error, exact prediction error, y_sim, u)`` of a generic effect over the
    whole record, as :func:`evaluate_batch` gives for kernel effects."""
    T = int(np.shape(v)[0])
    vp, yp, _ = _bucketed(v, y)
    return tuple(a[:T] for a in _evaluate_terms(cls, lay, theta, params, consts, vp, yp,
                                                criterion))


@eqx.filter_jit
def _evaluate_terms(cls, lay, theta, params, consts, v, y, criterion):
    if getattr(cls, "fit_error", None) is not None:  # scales from the context's consts
        effect = cls.from_params(base_model(lay, theta), params, consts)
    else:
        effect = cls.from_params(base_model(lay, theta), params)
    y_sim = effect.simulate_trajectory(v, jnp.zeros_like(v), 0.0)
    u = play_gather(lay, theta, consts, v)
    u = u + effect.input_term(v, u)
    eps = y - effect.predict_trajectory(v, y, 0.0)
    return term_error(cls, lay, theta, params, consts, v, y, criterion), eps, y_sim, u
