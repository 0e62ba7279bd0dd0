"""The physics library of the diagnosis: model extensions of the HB-Hammerstein model.

Each class wraps a nominal :class:`hbjax.Hammerstein` (``base``) and adds one physical
mechanism the paper's model (eq. (10)) leaves out. They are plain final ``eqx.Module``s
(array leaves for fitted values, static ints/floats for structure) subclassing
:class:`hbjax.AbstractModel`, so :func:`hbjax.simulate` and :func:`hbjax.predict` run them.
All of them evaluate through the single extended simulator of
:mod:`hbjax._diagnose.kernel` with the other extensions at their neutral values.

The one-step predictor of every extension is ``y_hat = y - D A (y - y_sim)``: for the
nominal model this is exactly the ARX predictor of eq. (10).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .kernel import Layout, simulate_full, whiten
from .._core.model import AbstractModel, Hammerstein

NO_CHANGE = 2**30  # change time "after the end of any record"


def layout_of(base: Hammerstein) -> Layout:
    return Layout(base.arx.na, base.arx.nb, base.backlash.m)


def base_theta(base: Hammerstein):
    lay = layout_of(base)
    return lay, lay.neutral(base.arx.a, base.arx.b, base.backlash.c1, base.backlash.c2)


def _consts(v_scale=1.0, y_center=0.0, y_scale=1.0, width=1.0):
    return jnp.asarray([v_scale, y_center, y_scale, width], dtype=jnp.float64)


def _ints(delay=0, time=NO_CHANGE):
    return jnp.asarray([delay, time], dtype=jnp.int32)


def _check_base(base):
    if not isinstance(base, Hammerstein):
        raise TypeError(f"`base` must be an hbjax.Hammerstein, got {type(base).__name__}.")


def _simulate(parts, v, noise, u0):
    lay, theta, ints, consts = parts
    return simulate_full(lay, theta, ints, consts, v, noise, u0)[0]


def _predict(parts, v, y, u0):
    lay, theta, ints, consts = parts
    y_sim = simulate_full(lay, theta, ints, consts, v, jnp.zeros_like(v), u0)[0]
    return y - whiten(lay, theta, ints, y, y_sim)


def _with(base, **values):
    lay, theta = base_theta(base)
    for name, val in values.items():
        if val is not None:
            theta = lay.put(theta, name, val)
    return lay, theta


class OutputSaturation(AbstractModel):
    """Output clipped to ``[lower, upper]`` (sensor range, overflow, ADC limit):
    ``y = clip(y_lin, lower, upper)``; ``None`` where that side is not clipped."""

    base: Hammerstein
    lower: Float[Array, ""] | None
    upper: Float[Array, ""] | None

    def parts(self):
        lay, theta = _with(self.base, out_lo=self.lower, out_hi=self.upper)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class InputSaturation(AbstractModel):
    """Actuator limit on the internal signal: ``u_s = clip(HB(v), lower, upper)`` drives
    the linear block; ``None`` where that side is not limited."""

    base: Hammerstein
    lower: Float[Array, ""] | None
    upper: Float[Array, ""] | None

    def parts(self):
        lay, theta = _with(self.base, in_lo=self.lower, in_hi=self.upper)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class ExtraDelay(AbstractModel):
    """``delay`` more samples of transport delay: the linear block sees ``u(t - delay)``
    (``u(t) = 0`` for ``t < 0``)."""

    base: Hammerstein
    delay: int = eqx.field(static=True)

    def parts(self):
        lay, theta = base_theta(self.base)
        return lay, theta, _ints(delay=self.delay), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class UnmodeledDynamics(AbstractModel):
    """One more pole and zero in the linear block: ``A + a_extra q^-(na+1)``,
    ``B + b_extra q^-(nb+1)``."""

    base: Hammerstein
    a_extra: Float[Array, ""]
    b_extra: Float[Array, ""]

    def parts(self):
        lay, theta = _with(self.base, a_extra=self.a_extra, b_extra=self.b_extra)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class ColoredNoise(AbstractModel):
    """Coloured equation error: ``A y = B u + xi / D`` with
    ``D = 1 + d[0] q^-1 + d[1] q^-2`` (an ARARX noise model). The simulation is the
    nominal one; the predictor whitens with ``D A``."""

    base: Hammerstein
    d: Float[Array, " 2"]

    def parts(self):
        lay, theta = _with(self.base, noise_d=self.d)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class OffsetDrift(AbstractModel):
    """Slow additive output drift: ``y = y_lin + offset + rate * t`` (t in samples)."""

    base: Hammerstein
    offset: Float[Array, ""]
    rate: Float[Array, ""]

    def parts(self):
        lay, theta = _with(self.base, drift_offset=self.offset, drift_rate=self.rate)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class ParameterChange(AbstractModel):
    """An abrupt change at sample ``time``: from then on the parameters are
    ``a + da``, ``b + db``, ``c1 + dc1``, ``c2 + dc2``."""

    base: Hammerstein
    time: int = eqx.field(static=True)
    da: Float[Array, " na"]
    db: Float[Array, " nb"]
    dc1: Float[Array, " m"]
    dc2: Float[Array, " m"]

    def parts(self):
        lay, theta = _with(self.base, da=self.da, db=self.db, dc1=self.dc1, dc2=self.dc2)
        return lay, theta, _ints(time=self.time), _consts()

    def after(self) -> Hammerstein:
        """The model in force after the change."""
        from .._core.arx import ARX
        from .._core.backlash import Backlash

        b = self.base
        return Hammerstein(Backlash(b.backlash.c1 + self.dc1, b.backlash.c2 + self.dc2),
                           ARX(b.arx.a + self.da, b.arx.b + self.db))

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class PeriodicDisturbance(AbstractModel):
    """An additive sinusoid unrelated to the input:
    ``y = y_lin + cos_amp cos(2 pi f t) + sin_amp sin(2 pi f t)``, ``f`` in cycles/sample."""

    base: Hammerstein
    frequency: Float[Array, ""]
    cos_amp: Float[Array, ""]
    sin_amp: Float[Array, ""]

    def parts(self):
        lay, theta = _with(self.base, sin_freq=self.frequency, sin_cos=self.cos_amp,
                           sin_sin=self.sin_amp)
        return lay, theta, _ints(), _consts()

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class OutputNonlinearity(AbstractModel):
    """A static curvature after the linear block (sensor nonlinearity):
    ``y = y_lin + scale (k2 z^2 + k3 z^3)``, ``z = (y_lin - center) / scale``."""

    base: Hammerstein
    k2: Float[Array, ""]
    k3: Float[Array, ""]
    center: float = eqx.field(static=True)
    scale: float = eqx.field(static=True)

    def parts(self):
        lay, theta = _with(self.base, nl2=self.k2, nl3=self.k3)
        return lay, theta, _ints(), _consts(y_center=self.center, y_scale=self.scale)

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class CoulombFriction(AbstractModel):
    """Dry (Coulomb) friction on the driven side: ``y = y_lin + force tanh(du / width)``,
    ``du(t) = u(t) - u(t-1)`` the motion of the backlash output (zero inside the gap)."""

    base: Hammerstein
    force: Float[Array, ""]
    width: float = eqx.field(static=True)

    def parts(self):
        lay, theta = _with(self.base, friction=self.force)
        return lay, theta, _ints(), _consts(width=self.width)

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


class BranchDegree(AbstractModel):
    """Backlash branches one degree higher than the base: ``P_k(v) + ck_extra (v/scale)^m``."""

    base: Hammerstein
    c1_extra: Float[Array, ""]
    c2_extra: Float[Array, ""]
    scale: float = eqx.field(static=True)

    def parts(self):
        lay, theta = _with(self.base, c1_extra=self.c1_extra, c2_extra=self.c2_extra)
        return lay, theta, _ints(), _consts(v_scale=self.scale)

    def simulate_trajectory(self, v, noise, u0):
        return _simulate(self.parts(), v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        return _predict(self.parts(), v, y, u0)


#: effect name -> the model class that expresses it (``parameter_mismatch`` is a refitted
#: :class:`hbjax.Hammerstein`).
EFFECTS = {
    "parameter_mismatch": Hammerstein,
    "output_saturation": OutputSaturation,
    "input_saturation": InputSaturation,
    "extra_delay": ExtraDelay,
    "unmodeled_dynamics": UnmodeledDynamics,
    "colored_noise": ColoredNoise,
    "offset_drift": OffsetDrift,
    "parameter_change": ParameterChange,
    "periodic_disturbance": PeriodicDisturbance,
    "output_nonlinearity": OutputNonlinearity,
    "coulomb_friction": CoulombFriction,
    "branch_degree": BranchDegree,
}
