"""Public simulation entry points: the play operator, free-run simulation, prediction."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .arx import ARX
from .backlash import Backlash
from .._misc import (
    as_float_array, check_finite, float_dtype, guard_finite, is_traced, same_length, signal,
)
from .buckets import bucket_length, pad, should_bucket
from .cache import ensure_compilation_cache
from .initial import injection, output_lags
from .model import AbstractModel, Hammerstein, play_trajectory
from .relaxed import relax


def _check_model(model, cls=AbstractModel, name="model"):
    if not isinstance(model, cls):
        raise TypeError(
            f"`{name}` must be an hbjax.{cls.__name__}, got {type(model).__name__}."
        )
    blocks = jax.tree_util.tree_leaves(model, is_leaf=lambda x: isinstance(x, (Backlash, ARX)))
    for block in blocks:
        # (the coefficient arrays only: a relaxed backlash also holds a scalar smoothing)
        coefficients = ([block.c1, block.c2] if isinstance(block, Backlash)
                        else [block.a, block.b] if isinstance(block, ARX) else [])
        if any(jnp.ndim(c) != 1 for c in coefficients):
            shapes = [tuple(jnp.shape(c)) for c in coefficients]
            raise ValueError(
                f"`{name}` is batched (coefficient shapes {shapes}, expected 1-D): pass one "
                f"{name} at a time, e.g. under jax.vmap over the batch.")


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


# Why an output may overflow, for the message under jit (where the cause cannot be looked at).
_WHY = {
    "simulate": "the simulated output overflows to inf/NaN: the model diverges (an unstable "
                "ARX block, assumption A3) or the input drives it beyond float range.",
    "play": "the play operator's output overflows to inf/NaN: both branches P1(v), P2(v) "
            "overflow at the largest |v|; rescale `v` or the coefficients.",
    "predict": "the one-step prediction overflows to inf/NaN: `v`, `y` or the model's "
               "coefficients are beyond float range; rescale the data.",
}


def _check_output(y, finite, model, what="simulate"):
    """Refuse an inf/NaN output (the inputs were finite): eagerly with a ``ValueError``
    naming the first bad sample and the cause, under jit/vmap with ``eqx.error_if``. The
    flag ``finite`` is reduced inside the compiled run (fused with the scan), so the check
    costs no extra pass over the record."""
    if is_traced(finite) or is_traced(y):
        if type(y).__name__ == "BatchTracer":  # (no public name for the vmap tracer)
            # Under vmap any check that the batched output depends on costs a copy of the
            # whole batch after the scan (measured 1.6-3x on benchmarks/simulate.py): the
            # lanes' records are returned as computed, inf/NaN included.
            return y
        # One sample carries the check (a copy of a scalar through the error's branch,
        # not of the record); the record's finiteness flag is fused with its computation.
        return y.at[-1].set(eqx.error_if(y[-1], ~finite, _WHY[what]))
    if bool(finite):
        return y
    first = int(np.flatnonzero(~np.isfinite(np.asarray(y)))[0])
    if what != "simulate":
        raise ValueError(f"{_WHY[what][:-1]} (from sample {first} on).")
    why = "the model diverges"
    if isinstance(model, Hammerstein) and model.arx.is_stable():
        # a stable block cannot diverge: what it was given is out of range
        why = ("`model` is stable, so the values given (`v`, `noise`, `u0`, `y0`) are too "
               "large for the output's precision")
    elif isinstance(model, Hammerstein):
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
def _play(backlash, v, u0, valid=None):
    u = play_trajectory(backlash, v, u0)
    return u, _all_finite(u, valid)


@eqx.filter_jit
def _simulate(model, v, noise, u0, y0=None, valid=None):
    if y0 is None:
        y = model.simulate_trajectory(v, noise, u0)
    else:  # the past enters the scan's initial carry: no extra pass over the record
        y = model.simulate_trajectory(v, noise, u0, y0=y0)
    # Fused with the scan: the divergence check costs no extra pass over y.
    return y, _all_finite(y, valid)


def _all_finite(y, valid):
    finite = jnp.isfinite(y)
    if valid is not None:  # the padded tail of a bucketed record does not count
        finite = finite | (jnp.arange(y.shape[0]) >= valid)
    return jnp.all(finite)


def _causal(fn, model, records, *rest, **kwargs):
    """``fn(model, *records, *rest)``; an eager call runs on records padded to their
    length's bucket (``buckets.py``: one compiled program for many lengths) and returns the
    first ``N`` samples, which the padding cannot change (the recursions are causal)."""
    limit = model.record_length() if isinstance(model, AbstractModel) else None
    if limit is not None and records[0].shape[0] > limit:
        raise ValueError(
            f"`v` has {records[0].shape[0]} samples, but the model carries signals recorded "
            f"with {limit} samples ({type(model).__name__}): it runs on that record or a "
            "prefix of it only.")
    if not should_bucket(model, records, rest):
        return fn(model, *records, *rest, **kwargs)
    n = records[0].shape[0]
    size = bucket_length(n)
    kwargs["valid"] = np.asarray(n)
    # Padding and slicing on the host: an eager jnp op would itself compile per length.
    out = fn(model, *(pad(r, size) for r in records), *rest, **kwargs)
    return jax.tree_util.tree_map(lambda a: jax.device_put(np.asarray(a)[:n]) if a.ndim else a,
                                  out)


def _smoothing(smoothing):
    """``None`` (exact operator) or a scalar >= 0, checked when concrete."""
    if smoothing is None:
        return None
    eps = as_float_array(smoothing, "smoothing")
    if eps.ndim != 0:
        raise ValueError(f"`smoothing` must be a scalar, got shape {tuple(eps.shape)}.")
    if is_traced(eps):  # under jit: a runtime error naming it, as the other value checks
        return eqx.error_if(eps, ~(jnp.isfinite(eps) & (eps >= 0)),
                            "`smoothing` must be a finite number >= 0.")
    if not (np.isfinite(float(eps)) and float(eps) >= 0):
        raise ValueError(f"`smoothing` must be a finite number >= 0, got {smoothing!r}.")
    return eps


def _relaxed_model(model, smoothing):
    eps = _smoothing(smoothing)
    if eps is None:
        return model
    if not isinstance(model, Hammerstein):
        raise TypeError(
            f"`smoothing` needs an hbjax.Hammerstein model, got {type(model).__name__}."
        )
    return eqx.tree_at(lambda m: m.backlash, model, relax(model.backlash, eps))


@eqx.filter_jit
def _predict(model, v, y, u0, y0=None, valid=None):
    y_hat = model.predict_trajectory(v, y, u0)
    if y0 is not None:
        y_hat = y_hat + injection(model, y0, u0, v.shape[0]).astype(y_hat.dtype)
    return y_hat, _all_finite(y_hat, valid)


def play(backlash: Backlash, v, *, u0=0.0, smoothing=None) -> Float[Array, " time"]:
    """The internal signal ``u = HB(P1, P2)(v)`` of the generalised play operator.

    ``u(t) = min(max(u(t-1), L(v(t))), H(v(t)))`` with ``u(-1) = u0``
    (paper Fig. 2; ``docs/conventions.md``).

    **Arguments:** `backlash` (a :class:`hbjax.Backlash`), `v` (input, shape ``(T,)``),
    `u0` (state before the first sample), `smoothing` (``None``: the exact operator; a
    number ``eps > 0``: the relaxed operator for training, ``max``/``min`` replaced by
    log-sum-exp smoothings at temperature ``eps (H(v) - L(v))``, whose derivative with
    respect to ``v`` is non-zero inside the band and which tends to the exact operator as
    ``eps -> 0``; ``docs/training.md``).

    **Returns:** ``u``, shape ``(T,)``, in the dtype of `v` and `backlash`.
    """
    ensure_compilation_cache()
    _check_model(backlash, Backlash, "backlash")
    v = signal(v, "v", finite=False)
    v = v.astype(float_dtype(backlash, v))
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v), backlash)
    eps = _smoothing(smoothing)
    if eps is not None:
        backlash = relax(backlash, eps)
    return _check_output(*_causal(_play, backlash, (v,), u0), backlash, "play")


def simulate(model: AbstractModel, v, noise=None, *, u0=0.0, y0=None,
             smoothing=None) -> Float[Array, " time"]:
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
    - `y0`: ``None`` for the zero initial conditions above, or the output lags before the
      first sample, most recent first: ``[y(-1), ..., y(-na)]`` (the order of ``a``;
      :class:`hbjax.Hammerstein` models only). With `y0` the record continues a past in
      which the play operator held ``u0``: the input lags are ``u(-j) = u0`` too, so a
      system at rest starts at rest (``y0 = B(1) u0 / A(1)`` gives no transient).
      :func:`hbjax.estimate_initial_state` estimates ``(y0, u0)`` from a recording.
    - `smoothing`: ``None`` for the exact play operator, or ``eps > 0`` for the relaxed one
      of :func:`hbjax.play` (:class:`hbjax.Hammerstein` models only): gradients with
      respect to `v` then flow inside the band, for training (``docs/training.md``).

    **Returns:** ``y``, shape ``(T,)``, in the dtype of `model`, `v` and `noise`.
    """
    ensure_compilation_cache()
    _check_model(model)
    model = _relaxed_model(model, smoothing)
    v = signal(v, "v", finite=False)
    if noise is None:  # (NumPy when eager: jnp.zeros_like would compile per length)
        noise = jnp.zeros_like(v) if is_traced(v) else np.zeros(v.shape, v.dtype)
    else:
        noise = signal(noise, "noise", finite=False)
        same_length(v=v, noise=noise)
    # One dtype for the whole run: float32 in, float32 out (training pipelines on GPUs).
    dtype = float_dtype(model, v, noise)
    v, noise = v.astype(dtype), noise.astype(dtype)
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v, noise=noise), model)
    if y0 is not None:
        y0 = output_lags(model, y0, dtype)
    return _check_output(*_causal(_simulate, model, (v, noise), u0, y0), model)


def predict(model: AbstractModel, v, y, *, u0=0.0, y0=None) -> Float[Array, " time"]:
    """One-step-ahead predictor ``y_hat(t) = -sum_i a_i y(t-i) + sum_i b_i u(t-i)``.

    The predictor of eq. (10) under the paper's equation-error noise: ``y - y_hat`` is the
    equation error ``xi`` when the model is right. Zero initial conditions as in
    :func:`simulate`, or, with `y0`, the past ``y(-i) = y0[i-1]``, ``u(-j) = u0`` (as in
    :func:`simulate`).

    **Returns:** ``y_hat``, shape ``(T,)``.
    """
    ensure_compilation_cache()
    _check_model(model)
    v = signal(v, "v", finite=False)
    y = signal(y, "y", finite=False)
    same_length(v=v, y=y)
    dtype = float_dtype(model, v, y)
    v, y = v.astype(dtype), y.astype(dtype)
    u0 = _guard_params(guard_finite(_scalar(u0, "u0"), v=v, y=y), model)
    if y0 is not None:
        y0 = output_lags(model, y0, dtype)
    return _check_output(*_causal(_predict, model, (v, y), u0, y0), model, "predict")
