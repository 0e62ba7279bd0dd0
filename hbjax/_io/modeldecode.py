"""Decoding model-file JSON into modules: the class a file names (never importing
anything), arrays and floats with their dtypes and shapes checked, and the checks of the
rebuilt modules (degree cap, finite coefficients, every class's ``__check_init__``: for the
diagnosis's effects their declared parameter constraints) before a model is returned."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._core.model import AbstractModel
from .modeltypes import (
    _DTYPES, _FLOATS, ModelFileError, _all_subclasses, _class_id, _legacy_alias,
    _registered_types,
)


def _resolve_class(class_id, extra, where: str):
    """The class a file names. Nothing is ever imported: only registered hbjax types (or their
    0.1.0 module-path aliases), classes passed in ``extra`` and :class:`hbjax.AbstractModel`
    subclasses already defined outside hbjax in this process are accepted."""
    if not isinstance(class_id, str):
        raise ModelFileError(f"`{where}.class` must be a string, got {class_id!r}.")
    registered = _registered_types()
    name = _legacy_alias(class_id) or class_id
    if name in registered:
        return registered[name]
    if name in {c.__name__ for c in [AbstractModel, *_all_subclasses(AbstractModel)]
                if c.__module__.split(".")[0] == "hbjax"}:
        raise ModelFileError(f"model type {class_id!r} at `{where}` is abstract: it has no instances.")
    for cls in list(extra) + [
        c for c in _all_subclasses(AbstractModel) if c.__module__.split(".")[0] != "hbjax"
    ]:
        if _class_id(cls) == class_id:
            return cls
    raise ModelFileError(
        f"unknown model class {class_id!r} at `{where}`: not a registered hbjax type "
        f"({', '.join(sorted(registered))}) nor an hbjax.AbstractModel subclass defined in this "
        "process (define or import the extension before loading, or pass it in `classes=`)."
    )


def _decode_float(x, where):
    if isinstance(x, bool):
        raise ModelFileError(f"`{where}` must be a number, got {x!r}.")
    if isinstance(x, (int, float)):
        return float(x)
    if isinstance(x, dict) and set(x) == {"float"} and x["float"] in ("nan", "inf", "-inf"):
        return float(x["float"])
    raise ModelFileError(f"`{where}` must be a number, got {x!r}.")


def _check_range(values, dtype, where):
    """A value its declared dtype cannot hold is named, not rounded to inf (float) or left
    to NumPy's overflow (integer)."""
    info = np.finfo(dtype) if dtype.startswith("float") else (
        np.iinfo(dtype) if dtype.startswith("int") else None)
    if info is None:
        return
    kind = float if dtype.startswith("float") else int
    low, high = kind(info.min), kind(info.max)  # (Python numbers: no cast of x to dtype)
    for i, x in enumerate(values):
        if (isinstance(x, int) or math.isfinite(x)) and not low <= x <= high:
            shown = f"{x:.6g}" if isinstance(x, float) else f"{float(x):.6g}" if len(
                str(x)) < 300 else "an integer of %d digits" % len(str(abs(x)))
            raise ModelFileError(f"`{where}[{i}]` ({shown}) is too large for its dtype "
                                 f"{dtype} (range {info.min:g} to {info.max:g}).")


def _decode_array(obj, where):
    if set(obj) - {"array", "dtype", "shape", "kind"} or not {"array", "dtype", "shape"} <= set(obj):
        raise ModelFileError(f"`{where}` is a malformed array entry (keys {sorted(obj)}).")
    dtype, shape, data = obj["dtype"], obj["shape"], obj["array"]
    kind = obj.get("kind", "jax")
    if kind not in ("jax", "numpy"):
        raise ModelFileError(f"`{where}.kind` must be 'jax' or 'numpy', got {kind!r}.")
    if dtype not in _DTYPES:
        raise ModelFileError(f"`{where}` has unsupported dtype {dtype!r}.")
    if not (isinstance(shape, list) and all(isinstance(s, int) and not isinstance(s, bool)
                                            and s >= 0 for s in shape)):
        raise ModelFileError(f"`{where}.shape` must be a list of sizes, got {shape!r}.")
    if not isinstance(data, list) or len(data) != math.prod(shape):
        raise ModelFileError(
            f"`{where}` must hold {math.prod(shape)} values for shape {tuple(shape)}, got "
            f"{len(data) if isinstance(data, list) else type(data).__name__}."
        )
    if dtype.startswith("float"):
        values = [_decode_float(x, f"{where}[{i}]") for i, x in enumerate(data)]
    elif dtype == "bool":
        if not all(isinstance(x, bool) for x in data):
            raise ModelFileError(f"`{where}` must hold booleans.")
        values = data
    else:
        if not all(isinstance(x, int) and not isinstance(x, bool) for x in data):
            raise ModelFileError(f"`{where}` must hold integers.")
        values = data
    _check_range(values, dtype, where)
    arr = np.array(values, dtype=dtype).reshape(shape)
    if kind == "numpy":
        return arr
    if arr.dtype.itemsize == 8 and not jax.config.jax_enable_x64:
        # JAX would store these in 32 bits: refuse a silent rounding (or overflow)
        narrow = arr.astype(np.float32 if arr.dtype.kind == "f" else np.int32)
        with np.errstate(invalid="ignore", over="ignore"):
            exact = np.array_equal(narrow.astype(arr.dtype), arr, equal_nan=arr.dtype.kind == "f")
        if not exact:
            raise ModelFileError(
                f"`{where}` holds {dtype} values that 32 bits cannot represent exactly, and "
                "JAX's 64-bit mode is off, so loading would change them. Turn it on before "
                "loading: jax.config.update('jax_enable_x64', True).")
    return jnp.asarray(arr)


def _decode(obj, extra, where):
    if obj is None or isinstance(obj, (bool, str, int, float)):
        return obj
    if isinstance(obj, list):
        raise ModelFileError(f"`{where}`: bare JSON lists are not part of the format.")
    if not isinstance(obj, dict):
        raise ModelFileError(f"`{where}`: unexpected value {obj!r}.")
    if "class" in obj:
        return _decode_module(obj, extra, where)
    if "array" in obj:
        return _decode_array(obj, where)
    if set(obj) == {"float"}:
        return _decode_float(obj, where)
    if set(obj) == {"tuple"} and isinstance(obj["tuple"], list):
        return tuple(_decode(x, extra, f"{where}[{i}]") for i, x in enumerate(obj["tuple"]))
    if set(obj) == {"list"} and isinstance(obj["list"], list):
        return [_decode(x, extra, f"{where}[{i}]") for i, x in enumerate(obj["list"])]
    if set(obj) == {"dict"} and isinstance(obj["dict"], dict):
        return {k: _decode(x, extra, f"{where}[{k!r}]") for k, x in obj["dict"].items()}
    raise ModelFileError(f"`{where}`: unrecognised entry with keys {sorted(obj)}.")


def _decode_module(obj, extra, where):
    if set(obj) != {"class", "fields"} or not isinstance(obj["fields"], dict):
        raise ModelFileError(f"`{where}` must be an object with `class` and `fields`.")
    cls = _resolve_class(obj["class"], extra, where)
    if getattr(cls, "__abstractmethods__", None):
        raise ModelFileError(f"`{where}`: class {obj['class']!r} is abstract.")
    fields = dataclasses.fields(cls)
    expected = [f.name for f in fields]
    given = obj["fields"]
    # a field added to a class later, with a default, is absent from the files written
    # before it: those files keep loading, with the default
    defaults = {f.name: f.default for f in fields if f.default is not dataclasses.MISSING}
    missing = [n for n in expected if n not in given and n not in defaults]
    unknown = [n for n in given if n not in expected]
    if missing or unknown:
        raise ModelFileError(
            f"`{where}` ({cls.__name__}) does not match the class: missing fields {missing}, "
            f"unknown fields {unknown}."
        )
    _check_degree(cls, given, where)
    values = {n: _decode(given[n], extra, f"{where}.{n}") if n in given else defaults[n]
              for n in expected}
    module = object.__new__(cls)
    for name, value in values.items():
        object.__setattr__(module, name, value)
    # The invariants the constructors would have enforced, most-derived class last (an
    # effect's parameter constraints among them: their errors name the class and field).
    for klass in reversed(cls.__mro__):
        check = klass.__dict__.get("__check_init__")
        if check is not None:
            try:
                check(module)
            except Exception as exc:
                raise ModelFileError(f"`{where}` ({cls.__name__}) is invalid: {exc}") from None
    _check_arrays(module, cls, where)
    return module


def _check_degree(cls, given, where):
    """Refuse a backlash polynomial beyond the degree cap before building any array."""
    from .._core.backlash import MAX_COEFFICIENTS, Backlash

    if not issubclass(cls, Backlash):
        return
    for name in ("c1", "c2"):
        entry = given.get(name)
        shape = entry.get("shape") if isinstance(entry, dict) else None
        if (isinstance(shape, list) and len(shape) == 1 and isinstance(shape[0], int)
                and shape[0] > MAX_COEFFICIENTS):
            raise ModelFileError(
                f"`{where}.{name}` has {shape[0]} coefficients (polynomial degree "
                f"{shape[0] - 1}); hbjax handles at most m = {MAX_COEFFICIENTS} coefficients "
                f"per branch (degree {MAX_COEFFICIENTS - 1})."
            )


def _check_arrays(module, cls, where):
    # Backlash and ARX validate in __init__, not __check_init__: repeat their essentials here.
    from .._core.arx import ARX
    from .._core.backlash import Backlash

    if isinstance(module, Backlash):
        c1, c2 = module.c1, module.c2
        if not (isinstance(c1, jax.Array) and isinstance(c2, jax.Array) and c1.ndim == 1
                and c1.shape == c2.shape and c1.shape[0] >= 1 and c1.dtype == c2.dtype
                and c1.dtype in _FLOATS):
            raise ModelFileError(
                f"`{where}` (Backlash) needs c1, c2 as JAX arrays (kind 'jax') of float64 or "
                "float32, 1-D, of equal length >= 1.")
        if not (np.all(np.isfinite(c1)) and np.all(np.isfinite(c2))):
            raise ModelFileError(f"`{where}` (Backlash) has non-finite coefficients.")
    if isinstance(module, ARX):
        a, b = module.a, module.b
        if not (isinstance(a, jax.Array) and isinstance(b, jax.Array) and a.ndim == 1
                and b.ndim == 1 and b.shape[0] >= 1 and a.dtype == b.dtype
                and a.dtype in _FLOATS):
            raise ModelFileError(f"`{where}` (ARX) needs a, b as JAX arrays (kind 'jax') of "
                                 "float64 or float32, 1-D, with nb >= 1.")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ModelFileError(f"`{where}` (ARX) has non-finite coefficients.")
