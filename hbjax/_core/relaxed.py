"""A relaxed (smoothed) play operator, for training through the backlash.

The exact operator ``u(t) = min(max(u(t-1), L(v(t))), H(v(t)))`` (paper Fig. 2) has a
derivative with respect to ``v(t)`` that is exactly zero whenever ``u(t-1)`` lies strictly
inside the band ``(L(v(t)), H(v(t)))``: the output holds its value. That is the physics,
but a network feeding ``v`` whose outputs start inside the band receives no gradient at
all and never moves (``docs/training.md``).

The relaxed operator replaces ``max`` and ``min`` by their log-sum-exp smoothings at a
temperature proportional to the band's width,

    ``tau(t) = eps * (H(v(t)) - L(v(t)))``,
    ``smax(a, b) = tau log(e^(a/tau) + e^(b/tau))``, ``smin(a, b) = -smax(-a, -b)``,
    ``u(t) = smin(smax(u(t-1), L(v(t))), H(v(t)))``,

so the input's weight in ``u(t)`` is a sigmoid of the distance to the band's edges in units
of ``tau``: never zero for ``eps > 0``, and the exact operator as ``eps -> 0`` (each step
is within ``tau log 2`` of the exact one, and the play operator does not amplify errors:
it is 1-Lipschitz in ``u(t-1)``). Where the band has zero width (``H = L``) the
temperature is zero and the exact operator is used, as where the temperature is below the
rounding of the values it smooths (a smoothing it cannot represent). Everything is computed in the dtype
of the inputs (float32 stays float32).
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .backlash import Backlash


def _smooth_max(a, b, tau, positive):
    safe = jnp.where(positive, tau, jnp.ones_like(tau))
    soft = safe * jnp.logaddexp(a / safe, b / safe)
    # the exact max where the band has no width: at a tie through `b` (the band edge), as
    # the exact operator (hbjax._core.backlash.play_step)
    return jnp.where(positive, soft, jnp.where(a == b, b, jnp.maximum(a, b)))


def _resolved(tau, a, b):
    """Where the temperature is above the rounding of the values it smooths, and its square
    above the dtype's smallest normal number: below either the smoothing changes nothing
    representable, or its derivative (``a / tau^2``) overflows into NaN gradients
    (``smoothing=1e-20`` in float32 gave 200 of 200; values of 1e-20 did at any ``eps``)."""
    info = jnp.finfo(tau.dtype)
    return (tau > info.eps * (jnp.abs(a) + jnp.abs(b))) & (tau > jnp.sqrt(info.tiny))


def relaxed_step(low, high, u_prev, eps):
    """One relaxed play step in the band ``[low, high]`` (sorted), temperature
    ``eps * (high - low)``."""
    tau = eps * (high - low)
    raised = _smooth_max(u_prev, low, tau, _resolved(tau, u_prev, low))
    return -_smooth_max(-raised, -high, tau, _resolved(tau, raised, high))


class RelaxedBacklash(Backlash):
    """A :class:`hbjax.Backlash` whose play step is the relaxed one of this module.

    Built by :func:`hbjax.play` and :func:`hbjax.simulate` from ``smoothing=eps``; the
    branches are the same (`c1`, `c2`), `smoothing` is the temperature as a fraction of
    the band's width.
    """

    smoothing: Float[Array, ""]

    def __init__(self, c1, c2, smoothing):
        super().__init__(c1, c2)
        self.smoothing = jnp.asarray(smoothing, dtype=self.c1.dtype)

    def step(self, u_prev, v):
        low, high = self.band(v)
        return relaxed_step(low, high, u_prev, self.smoothing)


def relax(backlash: Backlash, smoothing) -> Backlash:
    """``backlash`` with its play step relaxed at ``smoothing`` (``None``: unchanged)."""
    if smoothing is None:
        return backlash
    return RelaxedBacklash(backlash.c1, backlash.c2, smoothing)

