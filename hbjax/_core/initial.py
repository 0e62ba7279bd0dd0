"""Initial conditions of the HB-Hammerstein model: output lags before the first sample and
the play operator's state, given (:func:`hbjax.simulate`, :func:`hbjax.predict`) or
estimated from a recording (:func:`estimate_initial_state`, as MATLAB's
``'InitialCondition', 'e'``).

A past ``y(-i) = y0[i-1]`` (``i = 1..na``) and ``u(-j) = u0`` (``j = 1..nb``) enters the
recursion of eq. (10) only through the first ``n = max(na, nb)`` samples, as the known term

    ``d(t) = -sum_{i > t} a_i y0[i-t-1] + sum_{j > t} b_j u0``,  ``t = 0..n-1``,

so a run from that past equals a run from the paper's zero initial conditions with ``d``
added to the equation error: the output is affine in ``y0`` (the least squares of
:func:`estimate_initial_state`), and the predictor adds ``d`` to its output. The free run
itself starts its scan from the lags (``Hammerstein.simulate_trajectory(..., y0=...)``),
which costs nothing extra.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._misc import as_float_array, check_finite, is_traced, same_length, signal
from .arx import all_pole
from .model import AbstractModel, Hammerstein


class InitialState(eqx.Module):
    """An initial state of an HB-Hammerstein model.

    - `y0`: output lags before the first sample, most recent first:
      ``y0 = [y(-1), y(-2), ..., y(-na)]`` (the order of ``a``).
    - `u0`: the play operator's state ``u(-1)``; the linear block's input lags before the
      first sample are held at it (``u(-j) = u0``).
    - `cost`: sum of squared errors, on the record it was estimated from, of the run it was
      estimated for: the free run, or :func:`hbjax.compare`'s ``horizon``-step predictor.
    """

    y0: Float[Array, " na"]
    u0: Float[Array, ""]
    cost: Float[Array, ""]

    def __repr__(self):
        y0 = np.array2string(np.asarray(self.y0), precision=4)
        return f"InitialState(y0={y0}, u0={float(self.u0):.6g}, cost={float(self.cost):.6g})"


def output_lags(model: AbstractModel, y0, dtype=None) -> jax.Array:
    """``y0`` checked against ``model``: a Hammerstein model and ``na`` finite values."""
    if not isinstance(model, Hammerstein):
        raise TypeError(
            f"`y0` needs an hbjax.Hammerstein model (its ARX orders), got {type(model).__name__}."
        )
    y0 = as_float_array(y0, "y0", dtype=dtype)
    given = "a scalar" if y0.ndim == 0 else f"shape {tuple(y0.shape)}"
    if y0.ndim == 0:
        y0 = y0[None]
    na = model.arx.na
    if y0.shape != (na,):
        raise ValueError(
            f"`y0` must hold the na = {na} output lags [y(-1), ..., y(-{na})], got {given}."
            if na else f"`y0` must be empty: the model has no output lags (na = 0), got {given}."
        )
    return check_finite(y0, "y0")


def injection(model: Hammerstein, y0, u0, length: int) -> jax.Array:
    """The equation error ``d`` (module docstring) that a past ``(y0, u0)`` adds, padded
    or cut to ``length`` samples."""
    a, b = model.arx.a, model.arx.b
    na, nb = model.arx.na, model.arx.nb
    n = max(na, nb)
    terms = []
    for t in range(n):
        d_t = jnp.zeros((), jnp.result_type(a, y0, u0))
        for i in range(t + 1, na + 1):
            d_t = d_t - a[i - 1] * y0[i - t - 1]
        for j in range(t + 1, nb + 1):
            d_t = d_t + b[j - 1] * u0
        terms.append(d_t)
    d = jnp.stack(terms) if terms else jnp.zeros(0)
    if length <= n:
        return d[:length]
    return jnp.concatenate([d, jnp.zeros(length - n, d.dtype)])


def _basis(model: Hammerstein, length: int, dtype):
    """Free response to each output lag (``T x na``) and to ``u0`` in the input lags."""
    a = model.arx.a.astype(dtype)
    na = model.arx.na
    zero = jnp.zeros((), dtype)
    cols = [all_pole(a, injection(model, jnp.eye(na, dtype=dtype)[i], zero, length))
            for i in range(na)]
    h = jnp.stack(cols, axis=1) if na else jnp.zeros((length, 0), dtype)
    g = all_pole(a, injection(model, jnp.zeros(na, dtype), jnp.ones((), dtype), length))
    return h, g


_GRID = 33
_GOLDEN_STEPS = 30


@eqx.filter_jit
def _estimate(model: Hammerstein, v, y, n=None):
    """(``n``: the recorded samples of a record zero-padded to a bucket length, a runtime
    value: every row beyond them is left out, so one program serves the bucket.)"""
    T = v.shape[0]
    h, g = _basis(model, T, v.dtype)
    if n is not None:
        rows = jnp.arange(T) < n
        h, g, y = jnp.where(rows[:, None], h, 0.0), jnp.where(rows, g, 0.0), jnp.where(rows, y, 0.0)
    counted = (lambda x: x) if n is None else (lambda x: jnp.where(rows, x, 0.0))
    q = jnp.linalg.qr(h)[0]
    # Columns of 1/A that vanish within the record (a_na = 0) leave r singular: lstsq.
    solve = lambda res: jnp.linalg.lstsq(h, res)[0] if h.shape[1] else jnp.zeros(0, v.dtype)

    # the residual's part the output lags cannot absorb
    perp = lambda x: x - q @ (q.T @ x) if h.shape[1] else x

    def cost(u0):
        res = counted(y - model.simulate_trajectory(v, jnp.zeros_like(v), u0) - u0 * g)
        # ||perp(res)||^2, not ||res||^2 - ||q^T res||^2: where the output sits far from
        # zero the free run's start-up is huge and that difference cancels to rounding
        # (an exact model 1e7 output ranges from zero scored 98.4 % for its start)
        return jnp.sum(perp(res) ** 2), res

    bl = model.backlash
    p1, p2 = bl.p1(v[0]), bl.p2(v[0])
    lo, hi = jnp.minimum(p1, p2), jnp.maximum(p1, p2)
    grid = jnp.linspace(lo, hi, _GRID)
    costs = jax.vmap(lambda u: cost(u)[0])(grid)
    k = jnp.argmin(costs)
    step = (hi - lo) / (_GRID - 1)
    left, right = jnp.maximum(grid[k] - step, lo), jnp.minimum(grid[k] + step, hi)
    # a Python float (weakly typed): a NumPy float64 would widen a float32 model's bracket
    # and break the loop's carry type
    ratio = (5.0 ** 0.5 - 1.0) / 2.0

    def golden(_, bracket):
        x0, x1 = bracket
        c, d = x1 - ratio * (x1 - x0), x0 + ratio * (x1 - x0)
        keep_left = cost(c)[0] <= cost(d)[0]
        return jnp.where(keep_left, x0, c), jnp.where(keep_left, d, x1)

    x0, x1 = jax.lax.fori_loop(0, _GOLDEN_STEPS, golden, (left, right))
    inside = jnp.where(cost((x0 + x1) / 2)[0] <= costs[k], (x0 + x1) / 2, grid[k])

    # Beyond an edge of the band the play operator starts from that edge whatever u0 is,
    # and u0 is left only in the input lags, linearly: one least squares per side.
    g_perp = perp(g)

    def beyond(edge, side):
        r = perp(counted(y - model.simulate_trajectory(v, jnp.zeros_like(v), edge)))
        gg = jnp.sum(g_perp**2)
        # na >= nb: the output lags already span the input lags' response (g_perp ~ 0)
        free = gg > 1e-10 * jnp.sum(g**2)
        u = jnp.sum(g_perp * r) / jnp.where(free, gg, 1.0)
        return jnp.where(free & (side * (u - edge) > 0), u, edge)

    candidates = jnp.stack([inside, beyond(hi, 1.0), beyond(lo, -1.0)])
    u_best = candidates[jnp.argmin(jax.vmap(lambda u: cost(u)[0])(candidates))]
    _, res = cost(u_best)
    y0 = solve(res)
    # The reported cost is the squared error of the free run hbjax.simulate gives from
    # (y0, u0), not the search's ||res||^2 - ||proj||^2: that difference cancels to 0 where
    # the free run is huge (an unstable model 1e15 off the data reported a cost of 0).
    y_sim = model.simulate_trajectory(v, jnp.zeros_like(v), u_best, y0=y0)
    return InitialState(y0, u_best, jnp.sum(counted(y - y_sim) ** 2))


class FreeRunOverflow(ValueError):
    """A model's free run overflows (an unstable model, assumption A3), met by
    :func:`estimate_initial_state` or :func:`hbjax.compare`: a ``ValueError`` that callers
    with a fallback (another start, a ``-inf`` score) can tell apart from a bad argument."""


def estimate_initial_state(model: Hammerstein, v, y=None) -> InitialState:
    """Estimate the initial state (output lags ``y0`` and play state ``u0``) of a
    recording for a given model, as MATLAB's ``'InitialCondition', 'e'``.

    The free run from ``(y0, u0)`` is affine in ``y0`` (module docstring), so for every
    candidate ``u0`` the best ``y0`` is a linear least-squares fit of the whole record's
    free-run error. Inside the band ``[L(v(0)), H(v(0))]`` at the first input, ``u0`` is
    searched on a 33-point grid refined by golden-section search; beyond either edge the
    play operator starts from that edge and ``u0`` remains only in the input lags
    ``u(-j) = u0``, where it is linear: one least squares per side. When ``v(0)`` is
    outside the band and ``na >= nb``, the output lags absorb the input lags and only the
    play state's edge is determined (any such ``(y0, u0)`` gives the same free run).

    ``hbjax.simulate(model, v, u0=s.u0, y0=s.y0)`` reproduces the fitted free run. The
    input lags before the first sample are held at ``u0`` (a system at rest in its play
    state), as in :func:`hbjax.simulate` with ``y0``. So where ``nb > na`` and the record
    was cut from a run whose internal signal moved in the last ``nb`` samples before it,
    no ``(y0, u0)`` holds that past exactly and the free run from it misses the record's
    start (measured on noise-free cut records of random systems: 5 of 14 such records
    missed by up to 12 % of the output's range); :func:`hbjax.compare` fits those input
    lags as well and reproduces such a record.

    **Arguments:** `model` (an :class:`hbjax.Hammerstein`), `v`, `y` (the recording,
    equal lengths; or an :class:`hbjax.Recording` as `v`). Jit-compatible.

    **Returns:** an :class:`InitialState` ``(y0, u0, cost)``.
    """
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    # (the recording reader lives with the estimators, which import this module)
    from .._identify.recordings import as_input_output

    v, y, _ = as_input_output(v, y)
    v = signal(v, "v")
    y = signal(y, "y")
    same_length(v=v, y=y)
    dtype = jnp.result_type(v, y, model.arx.a)
    state = _estimate(model, v.astype(dtype), y.astype(dtype))
    if not any(is_traced(x) for x in (v, y, state.cost)) and not bool(
            jnp.isfinite(state.cost)):
        # the least squares of a free run that overflows: nothing to return but NaN
        raise FreeRunOverflow(f"the initial state cannot be estimated: {unstable_why(model)}.")
    return state


def unstable_why(model) -> str:
    """Why a model's free run overflowed, in words (the unstable ARX block of a Hammerstein
    model or of an extension's base, assumption A3)."""
    base = model if isinstance(model, Hammerstein) else getattr(model, "base", None)
    if isinstance(base, Hammerstein) and not base.arx.is_stable():
        radius = float(np.max(np.abs(np.asarray(base.arx.poles()))))
        return (f"the free run of `model` overflows: its ARX block is unstable (largest pole "
                f"modulus {radius:.4g}; assumption A3 asks < 1)")
    return "the free run of `model` overflows to inf/NaN"
