"""Argument checks of :func:`hbjax.monte_carlo` and the estimators it runs: the key, the
record lengths, the noise draw, the devices, the built-in estimators (closed form, and the
closed form refined) and the integer result code of one realisation.
"""

import inspect
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._identify.giri import estimate_giri
from .._misc import check_key, positive_int
from .._results import RESULTS


def check_study_key(key):
    """A threefry key: a realisation's draws are promised to depend on ``(key, N, r)``
    only, and the ``rbg`` implementations' draws under ``vmap`` change with the chunk
    size (measured: estimates 0.38 apart between two chunk sizes)."""
    key = check_key(key)
    if key.dtype == jnp.uint32:  # legacy jax.random.PRNGKey
        key = jax.random.wrap_key_data(key)
    impl = str(jax.random.key_impl(key))
    if "threefry" not in impl:
        raise ValueError(
            f"`key` must be a threefry2x32 key (jax.random.key(seed, impl='threefry2x32')), "
            f"got a {impl} key: its draws under vmap change with the chunk size, so a "
            "realisation's noise would not depend on (key, N, r) only.")
    return key


def check_lengths(lengths, design):
    if isinstance(lengths, (int, np.integer)) and not isinstance(lengths, bool):
        lengths = [lengths]
    if isinstance(lengths, (str, bytes)) or not isinstance(lengths, (Sequence, np.ndarray)):
        raise TypeError(f"`lengths` must be a sequence of integers, got {type(lengths).__name__}.")
    items = np.asarray(lengths, dtype=object)
    if items.ndim > 1 or any(np.ndim(n) > 0 for n in items.ravel()):
        # a nested list is not flattened: [[300, 600]] is a mistake, not two lengths
        raise TypeError("`lengths` must be a flat sequence of integers, got a nested one: "
                        f"{lengths!r}.")
    out = [positive_int(n, "lengths") for n in items.ravel()]
    if not out:
        raise ValueError("`lengths` must hold at least one record length.")
    minimum = max(design.staircase_period, design.binary_period)
    short = [n for n in out if n < minimum]
    if short:
        raise ValueError(
            f"`lengths` {short} are shorter than one period of v3 (2m(n+1) = "
            f"{design.staircase_period} samples for this design; v2's period is "
            f"{design.binary_period}): every record must cover at least {minimum} samples."
        )
    if len(set(out)) != len(out):
        raise ValueError(f"`lengths` must be distinct, got {out}.")
    return out


def noise_draw(noise, length):
    """``key -> unit-scale record (T,)`` for the white cases or the user's callable."""
    if noise in ("equation", "output"):
        return lambda k: jax.random.normal(k, (length,), jnp.float32).astype(jnp.float64)
    if not callable(noise):
        raise ValueError(
            f"`noise` must be 'equation', 'output' or a callable (key, length) -> record, "
            f"got {noise!r}."
        )
    try:
        n_args = len(inspect.signature(noise).parameters)
    except (TypeError, ValueError):
        n_args = 2
    draw = (lambda k: noise(k, length)) if n_args >= 2 else noise
    try:
        out = jax.eval_shape(draw, jax.random.key(0))
    except Exception as err:  # the user's code: say where it failed
        raise ValueError(f"calling the `noise` callable with (key, {length}) failed: {err}") from err
    if not hasattr(out, "shape") or out.shape != (length,) or not jnp.issubdtype(out.dtype, jnp.floating):
        got = f"shape {tuple(out.shape)} and dtype {out.dtype}" if hasattr(out, "shape") else repr(out)
        raise ValueError(
            f"the `noise` callable must return a float record of shape ({length},) for a "
            f"record length of {length}, got {got}."
        )
    return lambda k: draw(k).astype(jnp.float64)


def giri(design, y1, y2, y3):
    return estimate_giri(design, y1, y2, y3)


def refined(design, y1, y2, y3):
    """Closed form (the initial model), then prediction-error refinement on the three
    experiments. A failed closed form keeps its own result; otherwise the refinement's
    (one enumeration, :class:`hbjax.RESULTS`, for both)."""
    from .._identify.refine import refine_traceable

    first = estimate_giri(design, y1, y2, y3)
    length = y1.shape[0]
    inputs = (design.constant_input(length), design.binary_input(length),
              design.staircase_input(length))
    recordings = tuple((jnp.asarray(v), y) for v, y in zip(inputs, (y1, y2, y3)))
    res = refine_traceable(first.model, recordings, criterion="prediction", h_m=design.h_m,
                           max_steps=64)
    result = RESULTS.where(first.result != RESULTS.successful, first.result, res.result)
    return Outcome(res.model, result)


def result_code(result):
    """The int32 result code of one realisation from an estimator's ``.result``: an integer
    (or boolean) scalar, 0 = success. Refused at trace time when it is not an integer; a
    value outside the int32 range is clipped to its ends, so that a non-zero code never
    wraps to 0 (success)."""
    raw = getattr(result, "_value", result)
    try:
        raw = jnp.asarray(raw)
    except (TypeError, ValueError, OverflowError) as err:
        raise TypeError(
            "the `estimator`'s `.result` must be an integer result code (0 = success), got "
            f"{type(raw).__name__}: {err}"
        ) from None
    if not (jnp.issubdtype(raw.dtype, jnp.integer) or raw.dtype == jnp.bool_):
        raise TypeError(
            "the `estimator`'s `.result` must be an integer result code (0 = success), got "
            f"dtype {raw.dtype}; a float code such as 0.7 would be truncated to 0 (success)."
        )
    if raw.size != 1:
        raise ValueError(
            "the `estimator`'s `.result` must be one result code per realisation, got shape "
            f"{tuple(raw.shape)}."
        )
    raw = raw.reshape(())
    if raw.dtype == jnp.bool_:
        return raw.astype(jnp.int32)
    have, want = jnp.iinfo(raw.dtype), jnp.iinfo(jnp.int32)
    if have.min < want.min or have.max > want.max:
        raw = jnp.clip(raw, max(have.min, want.min), min(have.max, want.max))
    return raw.astype(jnp.int32)


def resolve_estimator(estimator):
    if estimator == "giri":
        return giri, "giri"
    if estimator == "refined":
        try:
            from .._identify.refine import refine_traceable  # noqa: F401
        except ImportError:
            raise NotImplementedError(
                "estimator='refined' needs hbjax._identify.refine.refine_traceable (prediction-error "
                "refinement, issue 3), which this installation does not have; use "
                "estimator='giri' or pass your own callable (design, y1, y2, y3) -> result "
                "with `.model` and `.result`."
            ) from None

        return refined, "refined"
    if callable(estimator):
        return estimator, getattr(estimator, "__name__", type(estimator).__name__)
    raise ValueError(
        f"`estimator` must be 'giri', 'refined' or a callable (design, y1, y2, y3) -> result "
        f"with `.model` and `.result`, got {estimator!r}."
    )


class Outcome:
    def __init__(self, model, result):
        self.model, self.result = model, result


def resolve_devices(devices):
    if devices is None:
        return list(jax.devices())
    if isinstance(devices, jax.Device):
        return [devices]
    what = "`devices` must be None or a non-empty sequence of jax.Device"
    # Checked before list(): a number or a string would fail there, or be split into letters.
    if isinstance(devices, (str, bytes)) or not isinstance(devices, (Sequence, np.ndarray)):
        raise TypeError(f"{what}, got {type(devices).__name__}.")
    devices = list(devices)
    if not devices:
        raise ValueError(f"{what}, got an empty sequence.")
    for d in devices:
        if not isinstance(d, jax.Device):
            raise TypeError(f"{what}, got an element of type {type(d).__name__}.")
    if len(set(devices)) != len(devices):
        raise ValueError(f"`devices` must list each device once (one shard per device), got "
                         f"{len(devices)} entries for {len(set(devices))} devices.")
    return devices
