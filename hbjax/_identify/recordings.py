"""Argument checks shared by refine, fit, separable_ls and crlb (eager, at call time)."""

import jax
import jax.numpy as jnp
import numpy as np

from .._misc import (
    as_float_array, check_values, holds_real_numbers, is_traced, one_device, positive_float,
    positive_int,
)
from .criteria import CRITERIA
from .._core.model import Hammerstein
from .._core.backlash import MAX_COEFFICIENTS


def _is_pair(x) -> bool:
    """``(v, y)``: two signals, where a signal may itself be a list of numbers (a list
    of records holds pairs, whose first item is no number)."""
    if not (isinstance(x, (tuple, list)) and len(x) == 2) or _is_recording(x[0]):
        return False
    if isinstance(x[0], (tuple, list)):  # two lists of numbers (their lengths checked later)
        return (_is_number_list(x[0]) and isinstance(x[1], (tuple, list))
                and _is_number_list(x[1]))
    return True


def _is_number_list(x) -> bool:
    return len(x) > 0 and not isinstance(x[0], (str, bytes)) and np.ndim(x[0]) == 0


def _is_recording(x) -> bool:
    return _is_frame(x) or (hasattr(x, "v") and hasattr(x, "y"))


def _is_frame(x) -> bool:
    # duck-typed: pandas stays optional and is never imported here
    return type(x).__name__ == "DataFrame" and hasattr(x, "iloc") and hasattr(x, "columns")


def _frame_column(x, k: int):
    """Column ``k`` of a DataFrame: real numbers as float64; anything else (complex, text,
    objects) as it is, for the array checks downstream to refuse by name rather than a
    cast to drop an imaginary part or parse text."""
    col = x.iloc[:, k]
    return col.to_numpy(np.float64) if holds_real_numbers(col.dtype) else col.to_numpy()


def recording_arrays(x):
    """``(v, y)`` of one recording given as an :class:`hbjax.Recording` (anything with
    ``.v`` and ``.y``) or a pandas ``DataFrame`` of two columns (input first, output
    second, e.g. ``df[["uEst", "yEst"]]``); ``None`` for anything else."""
    if _is_frame(x):
        if x.shape[1] != 2:
            raise ValueError(
                "a DataFrame given as a recording must have 2 columns, input then output; got "
                f"{list(x.columns)}: select them, e.g. df[['u', 'y']], or use "
                "hbjax.Recording.from_dataframe."
            )
        return _frame_column(x, 0), _frame_column(x, 1)
    if hasattr(x, "v") and hasattr(x, "y") and not isinstance(x, (tuple, list)):
        return x.v, x.y
    return None


def as_input_output(v, y=None):
    """``(v, y, dt)`` from input and output arrays, or from one recording (a
    :class:`hbjax.Recording` or a two-column DataFrame) given as `v` with `y` omitted;
    ``dt`` is the recording's sampling period (``None`` when unknown)."""
    if y is not None:
        if not isinstance(v, (np.ndarray, jax.Array)) and recording_arrays(v) is not None:
            raise TypeError("`v` is a recording, which holds its own output: pass it alone "
                            "(leave out `y`), or pass the input and output arrays.")
        return v, y, None
    pair = recording_arrays(v)
    if pair is None:
        raise TypeError("`y` is missing: pass `v` and `y`, or an hbjax.Recording or a "
                        "two-column pandas DataFrame (input, output) as `v`.")
    return pair[0], pair[1], getattr(v, "dt", None)


def as_recordings(recordings, name: str = "recordings", *, model=None, host: bool = False):
    """One ``(v, y)`` pair, a recording (:func:`recording_arrays`), or a list of those -> a tuple
    of ``(v, y)`` float64 pairs, each finite, 1-D, of equal lengths within the pair, on the
    same device as each other and as ``model`` (when given). ``host=True`` leaves records
    given as NumPy data on the host (for :func:`hbjax._core.buckets.padded_records`, which
    pads them there and transfers them once)."""
    single = recording_arrays(recordings)
    if single is not None:
        items = [single]
    elif _is_pair(recordings):
        items = [tuple(recordings)]
    elif isinstance(recordings, (tuple, list)) and len(recordings) > 0:
        items = []
        for k, rec in enumerate(recordings):
            rec = recording_arrays(rec) or rec
            if not _is_pair(rec):
                raise TypeError(
                    f"`{name}[{k}]` must be a (v, y) pair of 1-D arrays, got "
                    f"{type(rec).__name__}."
                )
            items.append(tuple(rec))
    else:
        raise TypeError(
            f"`{name}` must be a (v, y) pair or a non-empty list of (v, y) pairs, got "
            f"{type(recordings).__name__}."
        )
    out = []
    for k, (v, y) in enumerate(items):
        tag = f"{name}[{k}]" if len(items) > 1 else name
        v = as_float_array(v, f"{tag} v", ndim=1, dtype=jnp.float64, host=host)
        y = as_float_array(y, f"{tag} y", ndim=1, dtype=jnp.float64, host=host)
        if v.shape[0] != y.shape[0]:
            raise ValueError(
                f"records must have equal lengths: in `{tag}`, v has {v.shape[0]} samples "
                f"and y has {y.shape[0]}."
            )
        if v.shape[0] < 2:
            raise ValueError(f"`{tag}` must hold at least 2 samples, got {v.shape[0]}.")
        out.append((check_values(v, f"{tag} v"), check_values(y, f"{tag} y", output=True)))
    named = {f"{name}[{k}] {side}": arr for k, pair in enumerate(out)
             for side, arr in zip("vy", pair)}
    one_device(**named, model=model)
    return tuple(out)


def total_samples(recordings) -> int:
    return sum(int(v.shape[0]) for v, _ in recordings)


def check_branch_degree(m, name: str = "m") -> int:
    """``m`` for an identification: at least 2, since ``m = 1`` makes both branches
    constants, whose play operator output never follows the input."""
    m = positive_int(m, name)
    if m < 2:
        raise ValueError(
            f"`{name}` must be an integer >= 2 to identify a model, got {m}: with m = 1 both "
            "branches are constants, the backlash output never follows the input and the "
            "input has no effect on the output.")
    if m > MAX_COEFFICIENTS:
        raise ValueError(
            f"`{name}` must be at most {MAX_COEFFICIENTS} (coefficients per branch, degree "
            f"{MAX_COEFFICIENTS - 1}), got {m}.")
    return m


def check_criterion(criterion, also: tuple = ()) -> str:
    """`criterion` if it is one of :data:`CRITERIA` (or of `also`, a caller's own
    choices), else a ``ValueError`` naming them."""
    if criterion not in CRITERIA + tuple(also):
        raise ValueError(f"`criterion` must be one of {tuple(also) + CRITERIA}, got "
                         f"{criterion!r}.")
    return criterion


def check_h_m(h_m):
    """``None`` (static-gain normalisation), a traced value, or a finite number > 0.

    A number is returned as a float64 array: the compiled estimators take it as a runtime
    value, so a new amplitude compiles nothing (a Python float would be a static argument
    of ``filter_jit``, one compilation per value)."""
    if h_m is None or is_traced(h_m):
        return h_m
    # A NumPy scalar array: the jitted estimator transfers it with its other arguments
    # (an eager `jnp.asarray` is a device dispatch of its own).
    return np.asarray(positive_float(h_m, "h_m"), np.float64)


def check_model(model, name: str = "model") -> None:
    """A concrete-shaped, unbatched :class:`hbjax.Hammerstein`."""
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`{name}` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    for field, arr in (("a", model.arx.a), ("b", model.arx.b), ("c1", model.backlash.c1),
                       ("c2", model.backlash.c2)):
        if jnp.ndim(arr) != 1:
            raise ValueError(
                f"`{name}` must be a single model: its `{field}` has shape "
                f"{tuple(jnp.shape(arr))} (1-D expected; vmap refine_traceable for batches)."
            )
    if model.backlash.c1.shape != model.backlash.c2.shape:
        raise ValueError(
            f"`{name}` has branches of different sizes: c1 {model.backlash.c1.shape}, "
            f"c2 {model.backlash.c2.shape}."
        )
    leaves = [x for x in jax.tree_util.tree_leaves(model) if not is_traced(x)]
    if any(not np.all(np.isfinite(np.asarray(x))) for x in leaves):
        raise ValueError(f"`{name}` has non-finite parameters.")

