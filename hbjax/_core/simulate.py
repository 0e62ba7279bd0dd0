"""Public simulation entry points: the play operator, free-run simulation, prediction."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .arx import ARX
from .backlash import Backlash
from .._misc import as_float_array, check_finite, guard_finite, is_traced, same_length, signal
from .model import AbstractModel, Hammerstein, play_trajectory


def _check_model(model, cls=AbstractModel, name="model"):
    if not isinstance(model, cls):
        raise TypeError(
            f"`{name}` must be an hbjax.{cls.__name__}, got {type(model).__name__}."
        )


def _guard_params(carrier, model):
    """``eqx.error_if`` on traced Backlash/ARX coefficients (concrete ones are checked by
    the constructors). Other leaves of model extensions may be infinite on purpose (e.g.
    an inactive clip level), so only the paper's coefficients are guarded."""
    blocks = jax.tree_util.tree_leaves(model, is_leaf=lambda x: isinstance(x, (Backlash, ARX)))
    for block in blocks:
        if isinstance(block, (Backlash, ARX)):
            for leaf in jax.tree_util.tree_leaves(block):
                if is_traced(leaf):
                    carrier = eqx.error_if(
                        carrier, ~jnp.all(jnp.isfinite(leaf)),
                        "`model` has NaN or inf coefficients.",
                    )
    return carrier


def _check_output(y, finite, model):
    """Refuse a diverged free run eagerly instead of returning inf/NaN samples."""
    if is_traced(finite) or bool(finite):
        return y
    first = int(np.flatnonzero(~np.isfinite(np.asarray(y)))[0])
    why = "the model diverges"
    if isinstance(model, Hammerstein) and not model.arx.is_stable():
        radius = float(np.max(np.abs(np.asarray(model.arx.poles()))))
        why = (f"the ARX block of `model` is unstable (largest pole modulus {radius:.4g}; "
               "assumption A3 asks < 1)")
    raise ValueError(
        f"the simulated output overflows to inf/NaN from sample {first} on: {why}."
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
    y = model.simulate_trajectory(v, noise, u0)
    # Fused with the scan: the eager divergence check costs no extra pass over y.
    return y, jnp.all(jnp.isfinite(y))


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
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v), backlash)
    return _play(backlash, v, u0)


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
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v, noise=noise), model)
    return _check_output(*_simulate(model, v, noise, u0), model)


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
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v, y=y), model)
    return _predict(model, v, y, u0)
