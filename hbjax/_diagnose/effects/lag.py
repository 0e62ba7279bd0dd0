"""A first-order lag with a zero in series with the nominal linear block: the form of a
missing pole and zero that leaves the nominal dynamics as they are (the anchored variant
of ``unmodeled_dynamics``)."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import EffectConstraint
from ..explain import effect_windows, rounded
from .recursive import AbstractRecursiveEffect, arx_scan


class SeriesLag(AbstractRecursiveEffect):
    """The nominal linear block followed by ``L(q) = g (1 - zero q^-1) / (1 - pole q^-1)``
    with unit static gain (``g = (1 - pole) / (1 - zero)``): eq. (10) becomes

        ``A(q^-1) (1 - pole q^-1) y = g B(q^-1) (1 - zero q^-1) u + xi``,

    one pole and one zero more than the nominal model, its own poles and zeros kept. A
    sensor or actuator lag adds exactly this. :class:`UnmodeledDynamics` appends one
    coefficient to ``A`` and ``B``, which with the base re-estimated spans the same
    models, but with the base held at the nominal values cannot express a pole in series;
    this class is its anchored form (``UnmodeledDynamics.anchored_form``), reported under
    the same name."""

    base: Hammerstein
    pole: Float[Array, ""]
    zero: Float[Array, ""]

    name: ClassVar[str] = "unmodeled_dynamics"
    n_params: ClassVar[int] = 2
    noise_rival: ClassVar[str | None] = "colored_noise"  # as UnmodeledDynamics's
    constraints: ClassVar[dict] = {"pole": EffectConstraint(), "zero": EffectConstraint()}

    @classmethod
    def from_params(cls, base, params, consts=None):
        return cls(base, params[0], params[1])

    def params(self):
        return jnp.stack([jnp.asarray(self.pole), jnp.asarray(self.zero)])

    def blocks(self):
        """``(a, b)`` of the series connection (coefficients after the leading 1 of A)."""
        a = jnp.concatenate([jnp.ones(1), self.base.arx.a])
        a = jnp.convolve(a, jnp.array([1.0, -self.pole]))[1:]
        gain = (1.0 - self.pole) / (1.0 - self.zero)
        b = gain * jnp.convolve(self.base.arx.b, jnp.array([1.0, -self.zero]))
        return a, b

    def recursion(self, v, u, y_forced, noise):
        a, b = self.blocks()
        return arx_scan(a, b, u, noise, y_forced, lambda u_t, y_t, lags: (u_t, 0.0 * y_t))

    @classmethod
    def start(cls, ctx):
        """Poles from fast to slow, each with no zero and a zero on either side; the
        diagnosis starts from the one with the lowest criterion (a single start at a
        fast pole stays near it on a record whose missing lag is slow)."""
        return np.array([[p, z] for p in (0.2, 0.5, 0.8, 0.93) for z in (0.0, -0.4, 0.4)])

    @classmethod
    def scales(cls, ctx):
        return np.array([0.1, 0.2])

    def describe(self, ctx, info):
        pole, zero = float(self.pole), float(self.zero)
        return {
            "physics": ("The linear block needs one more pole and zero than the model has: a "
                        f"first-order lag (pole {rounded(pole, 3)}, zero {rounded(zero, 3)}, "
                        "unit static gain) in series with the nominal dynamics: unmodelled "
                        "dynamics (a sensor/actuator lag or a compliant mode)."),
            "where": {"windows": effect_windows(info),
                      "regime": "transients after input changes"},
            "parameters": {"pole": rounded(pole), "zero": rounded(zero)},
        }
