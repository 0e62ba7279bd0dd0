"""The linear block: an ARX equation-error model, paper eqs. (2) and (10)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._misc import as_float_array, is_traced, lag_sum
from . import display


class ARX(eqx.Module):
    """``A(q^-1) y(t) = B(q^-1) u(t) + xi(t)``, paper eq. (10).

    ``A = 1 + a[0] q^-1 + ... + a[na-1] q^-na`` and ``B = b[0] q^-1 + ... + b[nb-1] q^-nb``
    (no direct feed-through; leading zeros in ``b`` express a delay). The orders ``na``,
    ``nb`` are the static lengths of ``a`` and ``b``.
    """

    a: Float[Array, " na"]
    b: Float[Array, " nb"]

    def __init__(self, a, b):
        a = as_float_array(a, "a", ndim=1)
        b = as_float_array(b, "b", ndim=1)
        if b.shape[0] == 0:
            raise ValueError("`b` must hold at least one coefficient (nb >= 1), got shape (0,).")
        if not (is_traced(a) or is_traced(b)):
            if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
                raise ValueError("`a` and `b` must be finite.")
        self.a = a
        self.b = b

    @property
    def na(self) -> int:
        return self.a.shape[0]

    @property
    def nb(self) -> int:
        return self.b.shape[0]

    def poles(self):
        """Roots of ``z^na A(z^-1)``; assumption A3 asks them strictly inside the unit circle."""
        return jnp.roots(jnp.concatenate([jnp.ones(1), self.a]), strip_zeros=False)

    def pole_radius(self) -> float:
        """Largest pole modulus (0 without poles; concrete models only): assumption A3
        asks it below 1."""
        if self.na == 0:
            return 0.0
        return float(np.max(np.abs(np.roots(np.concatenate([[1.0], np.asarray(self.a, float)])))))

    def is_stable(self) -> bool:
        """Assumption A3 (concrete models only)."""
        return self.pole_radius() < 1

    def static_gain_numerator(self):
        """``B(1)``, nonzero under assumption A5."""
        return jnp.sum(self.b)

    def __repr__(self) -> str:
        return display.pformat(self)


def all_pole(a: Float[Array, " na"], x: Float[Array, "time ..."]) -> Float[Array, "time ..."]:
    """``x / A(q^-1)``: ``z(t) = x(t) - sum_i a_i z(t-i)`` with zero initial conditions (the
    free run of the linear block, eq. (2)), along the first axis of ``x`` (trailing axes are
    independent columns). The one home of this recursion for simulation-error criteria,
    initial-state estimation and the diagnosis."""
    na = a.shape[0]
    if na == 0:
        return x

    def step(lags, x_t):
        z_t = x_t
        for i in range(na):
            z_t = z_t - a[i] * lags[i]
        return (z_t,) + lags[:-1], z_t

    return jax.lax.scan(step, (jnp.zeros(x.shape[1:], x.dtype),) * na, x)[1]


def equation_error(a, b, y, u):
    """``A(q^-1) y - B(q^-1) u``, the equation error of eq. (10) with zero initial
    conditions, along the first axis: the prediction-error residual of the identification
    criteria and, on the extended model's signals, of the diagnosis (coefficients may be
    per-sample arrays, see :func:`hbjax._misc.lag_sum`)."""
    return y + lag_sum(a, y) - lag_sum(b, u)
