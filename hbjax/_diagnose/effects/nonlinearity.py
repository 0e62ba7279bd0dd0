"""Static nonlinear terms the nominal model lacks: sensor curvature after the linear
block, dry friction on the driven side and backlash branches one degree higher."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import EffectConstraint
from ..explain import effect_windows, rounded
from ..kernel_effect import AbstractKernelEffect
from ..residual_tests import windows


class OutputNonlinearity(AbstractKernelEffect):
    """A static curvature after the linear block (sensor nonlinearity):
    ``y = y_lin + scale (k2 z^2 + k3 z^3)``, ``z = (y_lin - center) / scale``."""

    base: Hammerstein
    k2: Float[Array, ""]
    k3: Float[Array, ""]
    center: float = eqx.field(static=True)
    scale: float = eqx.field(static=True)

    name: ClassVar[str] = "output_nonlinearity"
    slots: ClassVar[dict] = {"k2": "nl2", "k3": "nl3"}
    const_fields: ClassVar[dict] = {"center": 1, "scale": 2}
    constraints: ClassVar[dict] = {"k2": EffectConstraint(), "k3": EffectConstraint(),
                                   "center": EffectConstraint(),
                                   "scale": EffectConstraint(positive=True)}
    output_static: ClassVar[bool] = True

    @classmethod
    def candidate(cls, ctx):
        return cls.nominal_candidate(ctx, [("nl2", 1.0), ("nl3", 1.0)])

    def describe(self, ctx, info):
        ys = info["ysim"]
        z = np.linspace(-2, 2, 9)
        bend = float(self.scale) * (float(self.k2) * z**2 + float(self.k3) * z**3)
        worst = float(self.center + self.scale * z[int(np.argmax(np.abs(bend)))])
        return {
            "physics": ("The output depends nonlinearly on the linear block's output (sensor "
                        f"curvature): up to {rounded(np.max(np.abs(bend)))} off a straight "
                        f"line, most near output {rounded(worst)}."),
            "where": {"windows": effect_windows(info),
                      "output_range": [float(ys.min()), float(ys.max())],
                      "regime": f"output far from {rounded(self.center)}"},
            "parameters": {"k2": rounded(self.k2), "k3": rounded(self.k3),
                           "center": self.center, "scale": self.scale,
                           "max_deviation": rounded(np.max(np.abs(bend)))},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        center, scale = float(np.mean(signals["y0"])), signals["sy"]
        return cls(base, jnp.asarray(0.12), jnp.asarray(-0.05), center, scale), base, \
            {"k2": 0.12, "k3": -0.05}


class CoulombFriction(AbstractKernelEffect):
    """Dry (Coulomb) friction on the driven side: ``y = y_lin + force tanh(du / width)``,
    ``du(t) = u(t) - u(t-1)`` the motion of the backlash output (zero inside the gap)."""

    base: Hammerstein
    force: Float[Array, ""]
    width: float = eqx.field(static=True)

    name: ClassVar[str] = "coulomb_friction"
    slots: ClassVar[dict] = {"force": "friction"}
    const_fields: ClassVar[dict] = {"width": 3}
    constraints: ClassVar[dict] = {"force": EffectConstraint(),
                                   "width": EffectConstraint(positive=True)}

    @classmethod
    def candidate(cls, ctx):
        return cls.nominal_candidate(ctx, [("friction", 1.0)])

    def describe(self, ctx, info):
        u = info["u"]
        du = np.diff(u, prepend=u[0])
        moving = np.abs(du) > self.width
        return {
            "physics": (f"A force of about {rounded(abs(float(self.force)))} that only depends "
                        "on the direction of motion of the driven side: dry (Coulomb) "
                        "friction, flat while sliding and switching sign at each reversal."),
            "where": {"windows": windows(moving, min_gap=5),
                      "regime": "while the driven side moves (sign of du)",
                      "moving_fraction": float(np.mean(moving))},
            "parameters": {"force": rounded(self.force), "width": self.width},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        du = np.abs(np.diff(signals["u"]))
        width = 0.1 * float(np.median(du[du > 0]))
        force = 0.25 * signals["sy"]
        return cls(base, jnp.asarray(force), width), base, {"force": force}


class BranchDegree(AbstractKernelEffect):
    """Backlash branches one degree higher than the base: ``P_k(v) + ck_extra (v/scale)^m``."""

    base: Hammerstein
    c1_extra: Float[Array, ""]
    c2_extra: Float[Array, ""]
    scale: float = eqx.field(static=True)

    name: ClassVar[str] = "branch_degree"
    slots: ClassVar[dict] = {"c1_extra": "c1_extra", "c2_extra": "c2_extra"}
    const_fields: ClassVar[dict] = {"scale": 0}
    constraints: ClassVar[dict] = {"c1_extra": EffectConstraint(), "c2_extra": EffectConstraint(),
                                   "scale": EffectConstraint(positive=True)}

    @classmethod
    def candidate(cls, ctx):
        return cls.nominal_candidate(ctx, [("c1_extra", 1.0), ("c2_extra", 1.0)])

    def describe(self, ctx, info):
        m = self.base.backlash.m
        c1 = float(self.c1_extra) / self.scale**m
        c2 = float(self.c2_extra) / self.scale**m
        v = info["v"]
        return {
            "physics": (f"The backlash branches are curved beyond degree {m - 1}: a "
                        f"degree-{m} term (stiffening or softening of the transmission at "
                        "large input) is missing."),
            "where": {"windows": effect_windows(info),
                      "input_range": [float(v.min()), float(v.max())], "regime": "large |v|"},
            "parameters": {"degree": m, "c1_extra": c1, "c2_extra": c2},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        v, u = signals["v"], signals["u"]
        scale = float(np.max(np.abs(v)))
        extra = 0.25 * float(np.max(np.abs(u)))
        return cls(base, jnp.asarray(extra), jnp.asarray(extra), scale), base, \
            {"c_extra": extra / scale ** base.backlash.m}
