"""Public simulation entry points: the play operator, free-run simulation, prediction."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._backlash import Backlash
from ._checks import as_float_array, check_finite, guard_finite, same_length, signal
from ._model import AbstractModel, play_trajectory


def _check_model(model, cls=AbstractModel, name="model"):
    if not isinstance(model, cls):
        raise TypeError(
            f"`{name}` must be an hbjax.{cls.__name__}, got {type(model).__name__}."
        )


def _scalar(x, name):
    x = as_float_array(x, name)
    if x.ndim != 0:
        raise ValueError(f"`{name}` must be a scalar, got shape {tuple(x.shape)}.")
    return check_finite(x, name)


@eqx.filter_jit
def _play(backlash, v, u0):
    return play_trajectory(backlash, v, u0)


@eqx.filter_jit
def _simulate(model, v, noise, u0):
    return model.simulate_trajectory(v, noise, u0)


@eqx.filter_jit
def _predict(model, v, y, u0):
    return model.predict_trajectory(v, y, u0)


def play(backlash: Backlash, v, *, u0=0.0) -> Float[Array, " time"]:
    """The internal signal ``u = HB(P1, P2)(v)`` of the generalised play operator.

    ``u(t) = min(max(u(t-1), L(v(t))), H(v(t)))`` with ``u(-1) = u0``
    (paper Fig. 2; ``docs/conventions.md``).

    **Arguments:** `backlash` (a :class:`hbjax.Backlash`), `v` (input, shape ``(T,)``),
    `u0` (state before the first sample).

    **Returns:** ``u``, shape ``(T,)``.
    """
    _check_model(backlash, Backlash, "backlash")
    v = signal(v, "v", finite=False)
    return _play(backlash, v, guard_finite(_scalar(u0, "u0"), v=v))


def simulate(model: AbstractModel, v, noise=None, *, u0=0.0) -> Float[Array, " time"]:
    """Free-run output of ``model`` driven by ``v`` (paper eq. (10)).

    ``y(t) = -sum_i a_i y(t-i) + sum_i b_i u(t-i) + xi(t)`` with ``u = HB(v)``,
    ``y(t) = u(t) = 0`` for ``t < 0`` and ``u(-1) = u0`` for the play operator.

    Works under ``jax.jit``, ``jax.grad`` (with respect to the model) and ``jax.vmap``,
    e.g. ``jax.vmap(simulate, in_axes=(None, 1, 1), out_axes=1)`` on time-major
    ``(T, B)`` arrays.

    **Arguments:**

    - `model`: a :class:`hbjax.Hammerstein` (or an extension of it).
    - `v`: input record, shape ``(T,)``.
    - `noise`: equation error ``xi``, shape ``(T,)``, or ``None`` for none.
    - `u0`: play-operator state before the first sample.

    **Returns:** ``y``, shape ``(T,)``.
    """
    _check_model(model)
    v = signal(v, "v", finite=False)
    if noise is None:
        noise = jnp.zeros_like(v)
    else:
        noise = signal(noise, "noise", finite=False)
        same_length(v=v, noise=noise)
    u0 = guard_finite(_scalar(u0, "u0"), v=v, noise=noise)
    return _simulate(model, v, noise, u0)


def predict(model: AbstractModel, v, y, *, u0=0.0) -> Float[Array, " time"]:
    """One-step-ahead predictor ``y_hat(t) = -sum_i a_i y(t-i) + sum_i b_i u(t-i)``.

    The predictor of eq. (10) under the paper's equation-error noise: ``y - y_hat`` is the
    equation error ``xi`` when the model is right. Zero initial conditions as in
    :func:`simulate`.

    **Returns:** ``y_hat``, shape ``(T,)``.
    """
    _check_model(model)
    v = signal(v, "v", finite=False)
    y = signal(y, "y", finite=False)
    same_length(v=v, y=y)
    return _predict(model, v, y, guard_finite(_scalar(u0, "u0"), v=v, y=y))
