"""Dynamics whose gain and time constant change with the output level (a tank drained
through an orifice: Torricelli's outflow ~ sqrt(level))."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..explain import rounded
from .recursive import AbstractRecursiveEffect, arx_scan


class LevelDependentDynamics(AbstractRecursiveEffect):
    """The restoring part of the linear block scales with the level above an outlet.

    Writing eq. (10) as ``y(t) = y(t-1) - R(t) - A(1) outlet + B u(t)`` with
    ``R = (1 + a_1)(y(t-1) - outlet) + sum_{i>1} a_i (y(t-i) - outlet)`` (the outflow
    above the outlet level), the outflow is scaled by the level:

        ``y(t) = y(t-1) - s(t) R(t) - A(1) outlet + B u(t)``,
        ``s(t) = (depth / (y(t-1) - outlet))^alpha``, ``depth = y_mean - outlet``.

    For a first-order block the outflow is ``k (y - outlet)^(1 - alpha)``: Torricelli's
    law for ``alpha = 1/2``; locally the time constant and the gain both grow as
    ``(y - outlet)^alpha``. ``s = 1`` at the mean level, so ``alpha = 0`` is the nominal
    model. Fitted: ``alpha`` and ``log_depth`` (``depth = exp(log_depth) y_std``)."""

    base: Hammerstein
    alpha: Float[Array, ""]
    log_depth: Float[Array, ""]
    y_mean: Float[Array, ""]
    y_std: Float[Array, ""]

    name: ClassVar[str] = "level_dependent_dynamics"
    n_params: ClassVar[int] = 2

    @classmethod
    def from_params(cls, base, params, consts=None):
        mean, std = (0.0, 1.0) if consts is None else (consts[1], consts[2])
        return cls(base, params[0], params[1], jnp.asarray(mean), jnp.asarray(std))

    def params(self):
        return jnp.stack([jnp.asarray(self.alpha), jnp.asarray(self.log_depth)])

    @property
    def outlet(self):
        return self.y_mean - jnp.exp(self.log_depth) * self.y_std

    def scaling(self, level):
        """``s`` at output level ``level``. Below the outlet the law continues as its odd
        extension (``s`` from the distance to the outlet): the flow through the orifice
        then changes sign and stays of the same size. Clamping the distance instead
        made ``s`` 1000^alpha there, and a free run that starts below the outlet (every
        simulation from rest of a record whose level sits far from zero) was thrown
        into a growing oscillation."""
        depth = jnp.exp(self.log_depth) * self.y_std
        distance = jnp.maximum(jnp.abs(level - self.outlet), 1e-3 * depth)
        return (depth / distance) ** self.alpha

    def recursion(self, v, u, y_forced, noise):
        a, b = self.base.arx.a, self.base.arx.b
        na = a.shape[0]
        outlet = self.outlet
        gain_a = 1.0 + jnp.sum(a)

        def law(u_t, y_t, lags):
            # the term entering y(t+1): lags before y(t+1) are (y_t,) + lags[:-1]
            now = (y_t,) + lags[:-1]
            full = sum(a[i] * now[i] for i in range(na))  # sum_i a_i y(t+1-i)
            rest = now[0] + full - gain_a * outlet        # R(t+1)
            return u_t, (1.0 - self.scaling(now[0])) * rest

        return arx_scan(a, b, u, noise, y_forced, law)

    @classmethod
    def start(cls, ctx):
        """Exponents from none (the nominal model, so the fit never starts worse than the
        refit) through mild to Torricelli's, each with outlets at a few depths below the
        lowest level; the diagnosis starts from the one with the lowest criterion. A
        plant whose level swings over a small part of its depth (a deep outlet) shows
        only a mild scaling over the record, which Torricelli's exponent with a shallow
        outlet overstates: on such records every start at alpha = 1/2 simulated far worse
        than the nominal model and the fit stayed there."""
        y = ctx.y_fit
        mean, std = float(np.mean(y)), max(float(np.std(y)), 1e-12)
        low = mean - float(np.min(y))
        depths = [np.log(max(f * low, 0.05 * std) / std) for f in (1.05, 1.5, 3.0, 10.0)]
        return np.array([[alpha, d] for alpha in (0.0, 0.1, 0.25, 0.5) for d in depths])

    @classmethod
    def scales(cls, ctx):
        return np.array([0.2, 0.5])

    def describe(self, ctx, info):
        y = np.asarray(info["y"])
        alpha, outlet = float(self.alpha), float(self.outlet)
        lo, hi = (float(q) for q in np.quantile(y, [0.1, 0.9]))
        s_lo, s_hi = float(self.scaling(lo)), float(self.scaling(hi))
        ratio = s_lo / s_hi if s_hi > 0 else np.inf
        law = ("Torricelli's law (exponent 1/2)" if abs(1 - alpha - 0.5) <= 0.15 else
               f"not Torricelli's 1/2: fitted exponent {rounded(1 - alpha, 3)}")
        trend = "grow" if ratio > 1 else "shrink"
        return {
            "physics": (f"The dynamics depend on the output level: the outflow goes as "
                        f"(level - {rounded(outlet, 3)})^{rounded(1 - alpha, 3)} ({law}), "
                        f"so the time constant and the gain {trend} with the level, by a "
                        f"factor {rounded(ratio, 3)} from level {rounded(lo, 3)} to "
                        f"{rounded(hi, 3)}: a tank drained through an orifice."),
            "where": {"windows": [[0, len(y)]], "output_range": [lo, hi],
                      "regime": "output level"},
            "parameters": {"outflow_exponent": rounded(1 - alpha), "alpha": rounded(alpha),
                           "outlet_level": rounded(outlet),
                           "time_constant_ratio": rounded(ratio)},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        y0 = signals["y0"]
        mean, std = float(np.mean(y0)), max(float(np.std(y0)), 1e-12)
        depth = 1.2 * (mean - float(np.min(y0))) + 0.1 * std
        model = cls(base, jnp.asarray(0.5), jnp.asarray(np.log(depth / std)),
                    jnp.asarray(mean), jnp.asarray(std))
        return model, base, {"alpha": 0.5, "outlet": mean - depth}
