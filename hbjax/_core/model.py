"""The composite HB-Hammerstein model and the base class model extensions derive from."""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from . import display
from .._misc import lagged
from .arx import ARX
from .backlash import Backlash


class AbstractModel(eqx.Module):
    """A dynamic model from input ``v`` to output ``y`` that :func:`hbjax.simulate` and
    :func:`hbjax.predict` can run. :class:`Hammerstein` is the paper's model; the
    diagnosis module adds extensions (saturations, delays, drifts, ...) as subclasses.
    """

    @abc.abstractmethod
    def simulate_trajectory(
        self, v: Float[Array, " time"], noise: Float[Array, " time"], u0
    ) -> Float[Array, " time"]:
        """Free-run output for input ``v`` and equation error ``noise``."""

    @abc.abstractmethod
    def predict_trajectory(
        self, v: Float[Array, " time"], y: Float[Array, " time"], u0
    ) -> Float[Array, " time"]:
        """One-step-ahead prediction of ``y`` from past ``y`` and ``v``."""

    def record_length(self) -> int | None:
        """The most samples the model can run: ``None`` (any length) unless it carries
        signals recorded with one record (e.g. the channels of ``missing_input``), which
        it can run on that record or a prefix of it only."""
        return None

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return display.model_html(self)


def play_trajectory(backlash: Backlash, v: Float[Array, " time"], u0) -> Float[Array, " time"]:
    """The play operator over a record, ``u(-1) = u0``."""

    def step(u_prev, v_t):
        u_t = backlash.step(u_prev, v_t)
        return u_t, u_t

    _, u = jax.lax.scan(step, jnp.asarray(u0, v.dtype), v)
    return u


def arx_prediction(arx: ARX, u, y):
    """``-sum_i a_i y(t-i) + sum_i b_i u(t-i)``: the deterministic part of eq. (10)."""
    out = jnp.zeros_like(y)
    for i in range(arx.na):
        out = out - arx.a[i] * lagged(y, i + 1)
    for i in range(arx.nb):
        out = out + arx.b[i] * lagged(u, i + 1)
    return out


class Hammerstein(AbstractModel):
    """The HB-Hammerstein model of paper eq. (10): ``u = HB(P1, P2)(v)``, then
    ``A(q^-1) y = B(q^-1) u + xi``.

    **Arguments:**

    - `backlash`: a :class:`hbjax.Backlash`.
    - `arx`: a :class:`hbjax.ARX`.
    """

    backlash: Backlash
    arx: ARX

    def __check_init__(self):
        if not isinstance(self.backlash, Backlash):
            raise TypeError(f"`backlash` must be an hbjax.Backlash, got {type(self.backlash).__name__}.")
        if not isinstance(self.arx, ARX):
            raise TypeError(f"`arx` must be an hbjax.ARX, got {type(self.arx).__name__}.")

    def simulate_trajectory(self, v, noise, u0, y0=None):
        return self.free_run(v, noise, u0, y0)[1]

    def free_run(self, v, noise, u0, y0=None):
        """``(u, y)``: the play operator's output and the output of eq. (10) driven by
        ``noise``, from one scan (the free-run fit of a refined model needs both; where only
        ``y`` is used the compiler drops ``u``)."""
        # `y0` (output lags, most recent first) starts the recursion from a past with
        # u(-j) = u0 (hbjax.simulate); None keeps the paper's zero initial conditions.
        # One scalar carry per lag (a tuple, not a shifted array): orders are static, so
        # the scan body is straight-line code and vmapping over a trailing batch axis of
        # time-major arrays keeps every carry a contiguous vector.
        a, b = self.arx.a, self.arx.b
        na, nb = self.arx.na, self.arx.nb
        zero = jnp.zeros((), v.dtype)

        def step(carry, inputs):
            u_play, y_lags, u_lags = carry
            v_t, xi_t = inputs
            y_t = xi_t
            for i in range(na):
                y_t = y_t - a[i] * y_lags[i]
            for i in range(nb):
                y_t = y_t + b[i] * u_lags[i]
            u_t = self.backlash.step(u_play, v_t)
            y_lags = ((y_t,) + y_lags[:-1]) if na else y_lags
            u_lags = (u_t,) + u_lags[:-1]
            return (u_t, y_lags, u_lags), (u_t, y_t)

        u_init = jnp.asarray(u0, v.dtype)
        if y0 is None:
            init = (u_init, (zero,) * na, (zero,) * nb)
        else:
            init = (u_init, tuple(y0[i].astype(v.dtype) for i in range(na)), (u_init,) * nb)
        # Measured on CPU (benchmarks/simulate.py, 1000 x 10 000 time-major): unrolling two
        # samples saves 15-25% for n >= 2 but costs 70% for a first-order block.
        unroll = 2 if max(na, nb) >= 2 else 1
        _, (u, y) = jax.lax.scan(step, init, (v, noise), unroll=unroll)
        return u, y

    def predict_trajectory(self, v, y, u0):
        u = play_trajectory(self.backlash, v, u0)
        return arx_prediction(self.arx, u, y)
