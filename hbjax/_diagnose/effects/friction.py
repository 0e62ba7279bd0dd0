"""Dry and viscous friction opposing the output's own motion, inside the dynamics."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import EffectConstraint
from ..explain import rounded
from ..residual_tests import windows
from .recursive import AbstractRecursiveEffect, arx_scan

#: width of the smoothed sign, in standard deviations of the output
WIDTH = 0.05


class CoulombFrictionInLoop(AbstractRecursiveEffect):
    """Dry (Coulomb) and viscous friction opposing the motion of the driven side, inside
    the recursion (force in, velocity out). A rigid body ``m dy/dt = F - Fc sign(y) - c y``
    discretised: the linear block is driven by the net force

        ``A(q^-1) y = B(q^-1) [u - force tanh(y / width) - viscous y]``,

    ``u`` the backlash output (the applied force), ``y`` the output (velocity); the
    friction at time ``t`` depends on the output at ``t``, so it opposes the output's own
    motion in every later sample. ``width`` (fixed, 5% of the output's standard
    deviation) smooths the sign."""

    base: Hammerstein
    force: Float[Array, ""]
    viscous: Float[Array, ""]
    width: Float[Array, ""]

    name: ClassVar[str] = "coulomb_friction"
    n_params: ClassVar[int] = 2
    constraints: ClassVar[dict] = {"force": EffectConstraint(), "viscous": EffectConstraint(),
                                   "width": EffectConstraint(positive=True)}
    # A driven side whose velocity the output is integrates the applied force: equation
    # error then dominates every free run (held-out fits of 17-20 % for the nominal model,
    # the refit and the true friction alike on a generator record of size ratio 7.5), and
    # only one-step prediction can tell the models apart. A force that switches sign with
    # the motion is input-to-output dynamics no noise model makes, so a held-out prediction
    # gain counts where the friction beats colored_noise by the BIC margin. Over the 384
    # records of the six study seeds this reported friction on one record, of friction.
    noise_rival: ClassVar[str | None] = "colored_noise"

    @classmethod
    def from_params(cls, base, params, consts=None):
        width = jnp.asarray(1.0) if consts is None else WIDTH * jnp.asarray(consts[2])
        return cls(base, params[0], params[1], width)

    def params(self):
        return jnp.stack([jnp.asarray(self.force), jnp.asarray(self.viscous)])

    def recursion(self, v, u, y_forced, noise):
        a, b = self.base.arx.a, self.base.arx.b

        def law(u_t, y_t, lags):
            return u_t - self.force * jnp.tanh(y_t / self.width) - self.viscous * y_t, 0.0 * y_t

        return arx_scan(a, b, u, noise, y_forced, law)

    @classmethod
    def start(cls, ctx):
        """Friction forces of a few sizes relative to the driving force (the nominal
        backlash output's spread); the viscous term starts at zero."""
        su = float(np.std(ctx.u_nom)) or 1.0
        return np.array([[0.05 * su, 0.0], [0.2 * su, 0.0], [0.5 * su, 0.0]])

    @classmethod
    def scales(cls, ctx):
        su = float(np.std(ctx.u_nom)) or 1.0
        return np.array([0.1 * su, 0.1 * su / max(float(np.std(ctx.y_fit)), 1e-12)])

    def describe(self, ctx, info):
        y, ys = info["y"], info["ysim"]
        force, visc = float(self.force), float(self.viscous)
        u = np.asarray(info["u"])
        drive = float(np.quantile(np.abs(u - np.median(u)), 0.9)) or 1.0
        width = float(self.width)
        moving = np.abs(ys) > width
        dry = force > 0
        kind = ("dry (Coulomb) friction opposing the output's motion" if dry else
                "a force pushing along the output's motion (negative dry friction: the "
                "mechanism is not friction)")
        visc_txt = (f" and a viscous force of {rounded(visc)} per unit of output"
                    if abs(visc) * float(np.std(y)) > 0.05 * abs(force) else "")
        return {
            "physics": (f"Inside the dynamics, {kind}: a force of {rounded(abs(force))} "
                        f"({rounded(100 * abs(force) / drive, 3)}% of the driving force's "
                        f"range) that switches sign with the output{visc_txt}; the output "
                        "sticks near zero while the drive is below it and is reduced by it "
                        "while moving."),
            "where": {"windows": windows(moving, min_gap=5),
                      "regime": "sign of the output (motion direction)",
                      "moving_fraction": float(np.mean(moving))},
            "parameters": {"force": rounded(force), "viscous": rounded(visc),
                           "width": width, "force_fraction_of_drive":
                           rounded(abs(force) / drive)},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        su = float(np.std(signals["u"]))
        width = WIDTH * signals["sy"]
        force = 0.3 * su
        return cls(base, jnp.asarray(force), jnp.asarray(0.0), jnp.asarray(width)), base, \
            {"force": force}
