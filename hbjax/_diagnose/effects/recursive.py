"""Effects that act inside the recursion of the linear block: the output's own past
enters the dynamics through a nonlinear law (friction opposing the output's motion, an
outflow that depends on the level). They are generic effects (fitted with a ``jax.jacfwd``
Jacobian) with their own criterion: the one-step prediction error with the measured
output in the law (``criterion="prediction"``; for the nominal model exactly the ARX
equation error of eq. (10)) or the free-run output error (``"simulation"``)."""

from __future__ import annotations

import abc

import jax
import jax.numpy as jnp

from ..._core.model import play_trajectory
from ..effect_base import AbstractEffect, base_model
from ..kernel import play_gather


class AbstractRecursiveEffect(AbstractEffect):
    """An effect whose law acts inside the recursion. A concrete class gives
    :meth:`recursion`: the output from the backlash output ``u`` and, when ``y_forced``
    is given, the one-step prediction with the measured output in every lag."""

    @abc.abstractmethod
    def recursion(self, v, u, y_forced, noise):
        """Free-run output (``y_forced=None``) or one-step prediction of ``y_forced``."""

    def simulate_trajectory(self, v, noise, u0):
        return self.recursion(v, play_trajectory(self.base.backlash, v, u0), None, noise)

    def predict_trajectory(self, v, y, u0):
        u = play_trajectory(self.base.backlash, v, u0)
        return self.recursion(v, u, y, jnp.zeros_like(v))

    @classmethod
    def fit_error(cls, lay, theta, params, consts, v, y, criterion, u0=0.0):
        """Prediction error (measured output in the law) or output error of the effect."""
        effect = cls.from_params(base_model(lay, theta), params, consts)
        u = play_gather(lay, theta, consts, v, u0)
        forced = None if criterion == "simulation" else y
        return y - effect.recursion(v, u, forced, jnp.zeros_like(y))

    @classmethod
    def from_fit(cls, ctx, theta, ints, params=None):
        return cls.from_params(base_model(ctx.lay, theta), jnp.asarray(params), ctx.consts)


def arx_scan(a, b, u, noise, y_forced, feedback, varying=None, sequential=False):
    """``y(t) = -sum_i a_i y(t-i) + sum_j b_j w(t-j) + noise(t) + extra(t)`` with
    ``(w(t), extra(t+1)) = feedback(u(t), y(t), lags)``: ``w`` the linear block's input
    after the law, ``extra`` a term entering the next sample's equation directly;
    ``lags`` the output lags before ``y(t)`` (most recent first). With ``y_forced`` the
    lags hold the measured output (one-step prediction).

    ``varying(y(t)) -> (a', gain, offset)``, if given, makes the block depend on the level:
    the next sample's equation uses the coefficients ``a'`` (a sequence of ``na``) in place
    of ``a``, ``gain * b`` in place of ``b``, and adds ``offset``. The first sample has no
    past: its equation is the nominal one from rest (zero), as eq. (10). The one-step
    prediction runs without the scan (:func:`_forced`) unless ``sequential``."""
    na, nb = a.shape[0], b.shape[0]
    zero = jnp.zeros((), u.dtype)
    forced = y_forced is not None
    if forced and not sequential:
        return _forced(a, b, u, noise, y_forced, feedback, varying)
    ys = y_forced if forced else jnp.zeros_like(u)

    def step(carry, x):
        y_lags, w_lags, extra, (a_t, gain_t) = carry
        u_t, xi_t, ym_t = x
        y_t = xi_t + extra
        for i in range(na):
            y_t = y_t - a_t[i] * y_lags[i]
        for j in range(nb):
            y_t = y_t + gain_t * b[j] * w_lags[j]
        y_src = ym_t if forced else y_t
        w_t, extra_next = feedback(u_t, y_src, y_lags)
        if varying is not None:
            a_next, gain_next, offset = varying(y_src)
            coefs, extra_next = (tuple(a_next), gain_next), extra_next + offset
        else:
            coefs = (a_t, gain_t)
        y_lags = (y_src,) + y_lags[:-1]
        w_lags = ((w_t,) + w_lags[:-1]) if nb else w_lags
        return (y_lags, w_lags, extra_next, coefs), y_t

    nominal = (tuple(a[i] for i in range(na)), jnp.ones((), u.dtype))
    init = ((zero,) * max(na, 1), (zero,) * nb, zero, nominal)
    return jax.lax.scan(step, init, (u, noise, ys))[1]


def _delayed(x, k, first):
    """``x(t - k)`` for every ``t``, ``first`` where ``t < k`` (the samples before the
    record, at rest)."""
    if k == 0:
        return x
    head = jnp.broadcast_to(jnp.asarray(first, x.dtype), (k,) + x.shape[1:])
    return jnp.concatenate([head, x[:-k]])


def _forced(a, b, u, noise, y_m, feedback, varying):
    """:func:`arx_scan`'s one-step prediction, without the scan. With the measured output
    in every lag, nothing a step computes feeds the next one's state: the law at ``t``
    sees ``u(t)``, ``y_m(t)`` and ``y_m``'s lags only. So the law runs over the whole
    record at once and the equation is a sum of delayed products, the scan's terms in
    the scan's order (the same numbers to rounding). On the level law's fit (5000 samples,
    ``jax.jacfwd`` Jacobian) each Levenberg-Marquardt step was most of a warm diagnosis'
    time inside the scan's sequential loop (benchmarks/RESULTS.md)."""
    na, nb = a.shape[0], b.shape[0]
    lags = tuple(_delayed(y_m, i + 1, 0.0) for i in range(max(na, 1)))
    w, extra = jax.vmap(feedback)(u, y_m, lags)
    gain = jnp.ones_like(u)
    if varying is not None:
        a_next, gain_next, offset = jax.vmap(varying)(y_m)
        # the first sample's equation is the nominal one (from rest, eq. (10))
        a_t = [_delayed(a_next[i], 1, a[i]) for i in range(na)]
        gain = _delayed(gain_next, 1, 1.0)
        extra = extra + offset
    else:
        a_t = [a[i] for i in range(na)]
    y = noise + _delayed(extra, 1, 0.0)
    for i in range(na):
        y = y - a_t[i] * lags[i]
    for j in range(nb):
        y = y + gain * b[j] * _delayed(w, j + 1, 0.0)
    return y
