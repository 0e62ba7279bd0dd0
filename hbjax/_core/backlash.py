"""The hysteresis-backlash HB(P1, P2): a play operator between two polynomial branches."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._misc import as_float_array, is_traced
from . import display


# Most coefficients per branch (degree + 1) a Backlash, and a model file, may have: far
# beyond any identifiable backlash, and it bounds the compiled programs (and file loads).
MAX_COEFFICIENTS = 64
# Up to this many coefficients Horner's rule is unrolled (fastest inside the simulator's
# scan); beyond, a lax.fori_loop keeps the compiled program small. Same operations, same order.
_UNROLL = 16


def polyval_ascending(c: Float[Array, " m"], v):
    """``c[0] + c[1] v + ... + c[m-1] v^(m-1)`` by Horner's rule (paper eq. (1))."""
    m = c.shape[0]
    out = jnp.zeros_like(v) + c[-1]
    if m <= _UNROLL:
        for k in range(m - 2, -1, -1):
            out = out * v + c[k]
        return out
    return jax.lax.fori_loop(1, m, lambda i, acc: acc * v + c[m - 1 - i], out)


def power_columns(v: Float[Array, " time"], m: int) -> Float[Array, "time m"]:
    """``[1, v, v^2, ..., v^(m-1)]`` as columns, by repeated multiplication: the regressors
    of eq. (1). ``v ** arange(m)`` would call ``pow`` per entry, which dominated the cost of
    the refinement Jacobian."""
    cols = [jnp.ones_like(v)]
    for _ in range(1, m):
        cols.append(cols[-1] * v)
    return jnp.stack(cols, axis=-1)


def play_step(u_prev, low, high):
    """One sample of the play operator, ``u(t) = min(max(u(t-1), low(t)), high(t))``
    (NOTES.md): the one expression of the clamp, shared by :meth:`Backlash.step`,
    :func:`play_sources` and the diagnosis kernel's extended recursion.

    The values are ``min``/``max``'s (NaN propagates); at a tie the derivative is taken
    through the band edge at ``t`` rather than split half and half with ``u(t-1)`` as
    ``jnp.maximum`` does: with identical branches (``P1 = P2``, a static nonlinearity) and
    a held input, ``u(t) = P(v(t))`` whatever the past, and only the edge carries its
    derivative ``P'(v(t))``; at a real edge it is the derivative for a rising ``v(t)``
    there, one of the kink's one-sided derivatives."""
    raised = jnp.where(u_prev == low, low, jnp.maximum(u_prev, low))
    return jnp.where(raised == high, high, jnp.minimum(raised, high))


def clamp_edges(u_prev, low, high):
    """``(to_high, to_low)``: whether the play operator's output at a sample is the upper
    edge ``high`` there (``max(u(t-1), low) > high``) or else the lower edge ``low``
    (``u(t-1) < low``); neither: ``u(t) = u(t-1)``. Those samples are the source instants
    of :func:`play_sources` (elementwise: also on whole records given ``u(t-1)``)."""
    to_high = jnp.maximum(u_prev, low) > high
    return to_high, ~to_high & (u_prev < low)


def play_sources(low: Float[Array, " time"], high: Float[Array, " time"], force=None, *,
                 u0=0.0):
    """The play operator ``u(t) = min(max(u(t-1), low(t)), high(t))`` (``u(-1) = u0``)
    and, for every ``t``, the instant whose band edge ``u(t)`` equals: ``src(t) = s`` if
    ``u(t) = low(s)``, ``T + s`` if ``u(t) = high(s)``, ``-1`` while still ``u(-1)``.

    The one scan of the play operator under the identification criteria and the
    diagnosis kernel: ``u(t)`` is a branch value at a source instant, so derivatives are
    gathers of the branches there instead of tangents through the loop.

    ``force`` (optional, int per sample) overrides the clamp where the band is inverted
    (``low > high``): 0 takes ``low``, 1 takes ``high``, 2 keeps ``u(t-1)``, -1 clamps.
    The scan body is a few selects; all the arithmetic is vectorised outside it.
    """
    T = low.shape[0]

    def step(carry, inputs):
        u_prev, src_prev = carry
        lo, hi, t, f = inputs
        to_high, to_low = clamp_edges(u_prev, lo, hi)
        src = jnp.where(to_high, T + t, jnp.where(to_low, t, src_prev))
        u = play_step(u_prev, lo, hi)
        if f is not None:
            u = jnp.select([f == 0, f == 1, f == 2], [lo, hi, u_prev], u)
            src = jnp.select([f == 0, f == 1, f == 2], [t, T + t, src_prev], src)
        return (u, src), (u, src)

    init = (jnp.asarray(u0, low.dtype), jnp.asarray(-1, jnp.int32))
    f = None if force is None else force.astype(jnp.int32)
    xs = (low, high, jnp.arange(T, dtype=jnp.int32), f)
    _, (u, src) = jax.lax.scan(step, init, xs)
    return u, src


def source_edges(src):
    """``(idx, on_high, valid)`` of :func:`play_sources`'s ``src``: the source instant
    (0 where there is none), whether ``u(t)`` is the upper edge ``high(idx)`` there, and
    whether ``u(t)`` has a source (else it is still ``u(-1)``). The one decoding of the
    source indices, shared by the criteria's Jacobian and the diagnosis kernel's gather."""
    T = src.shape[0]
    valid = src >= 0
    on_high = src >= T
    return jnp.where(valid, jnp.where(on_high, src - T, src), 0), on_high, valid


def gather_play(low, high, src, u0=0.0):
    """The play operator's output as a gather of band edges at the source instants of
    :func:`play_sources` (differentiable in ``low`` and ``high`` for fixed sources)."""
    idx, on_high, valid = source_edges(src)
    return jnp.where(valid, jnp.where(on_high, high[idx], low[idx]), u0)


class Backlash(eqx.Module):
    """Hysteresis-backlash flanked by two polynomials, paper eq. (1) and Fig. 2.

    ``P1(v) = sum_i c1[i] v^i`` is the branch a large rising input drives the output onto,
    ``P2`` the branch of a large falling input. The operator is the generalised play
    ``u(t) = min(max(u(t-1), L(v(t))), H(v(t)))`` with ``L = min(P1, P2)`` and
    ``H = max(P1, P2)`` pointwise (``docs/conventions.md``).

    **Arguments:**

    - `c1`: coefficients of ``P1`` in ascending powers, shape ``(m,)``.
    - `c2`: coefficients of ``P2`` in ascending powers, shape ``(m,)``.
    """

    c1: Float[Array, " m"]
    c2: Float[Array, " m"]

    def __init__(self, c1, c2):
        c1 = as_float_array(c1, "c1", ndim=1)
        c2 = as_float_array(c2, "c2", ndim=1)
        if c1.shape[0] == 0:
            raise ValueError("`c1` must hold at least one coefficient, got shape (0,).")
        if c1.shape[0] > MAX_COEFFICIENTS:
            raise ValueError(
                f"`c1` has {c1.shape[0]} coefficients (degree {c1.shape[0] - 1}); a backlash "
                f"branch has at most m = {MAX_COEFFICIENTS} coefficients (degree "
                f"{MAX_COEFFICIENTS - 1})."
            )
        if c1.shape != c2.shape:
            raise ValueError(
                "`c1` and `c2` must have the same length m (the paper's common degree "
                f"m-1), got {c1.shape[0]} and {c2.shape[0]}."
            )
        if not (is_traced(c1) or is_traced(c2)):
            # NumPy, not jnp: inside jit even constant jnp operations are traced.
            if not (np.all(np.isfinite(c1)) and np.all(np.isfinite(c2))):
                raise ValueError("`c1` and `c2` must be finite.")
        self.c1 = c1
        self.c2 = c2

    @property
    def m(self) -> int:
        """Number of coefficients per branch (polynomial degree + 1)."""
        return self.c1.shape[0]

    def p1(self, v):
        """Rising branch ``P1(v)``."""
        return polyval_ascending(self.c1, v)

    def p2(self, v):
        """Falling branch ``P2(v)``."""
        return polyval_ascending(self.c2, v)

    def band(self, v) -> tuple[jax.Array, jax.Array]:
        """``(L(v), H(v))``, the band the play operator keeps its output in."""
        a, b = self.p1(v), self.p2(v)
        return jnp.minimum(a, b), jnp.maximum(a, b)

    def step(self, u_prev, v):
        """One sample of the play operator: clamp the last output into the band at v."""
        return play_step(u_prev, *self.band(v))

    def __repr__(self) -> str:
        return display.pformat(self)
