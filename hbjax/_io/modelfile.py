"""Model files: human-readable JSON that round-trips any hbjax model bit for bit.

The serializer is generic over dataclass fields (every ``eqx.Module`` is a dataclass), so the
paper's :class:`hbjax.Hammerstein` and extensions (subclasses of :class:`hbjax.AbstractModel`
with array fields, static ints/floats/None, tuples and nested modules) share one format::

    {"format": "hbjax-model", "format_version": 1, "hbjax_version": "0.1.0",
     "kind": "Hammerstein",
     "model": {"class": "Hammerstein",
               "fields": {"backlash": {"class": "Backlash", "fields": {...}},
                          "arx": {...}}}}

Arrays are ``{"array": [...], "dtype": "float64", "shape": [2]}`` with every float written as
the shortest decimal that reads back to the same float64 (Python's ``repr``), so
``load_model(save_model(m))`` equals ``m`` bitwise. Non-finite floats are written as
``{"float": "nan"}`` / ``"inf"`` / ``"-inf"`` (strict JSON has no NaN).

Loading never imports code named by the file: a class is accepted only if it is a registered
hbjax type (public names such as ``"Hammerstein"``; files of hbjax 0.1.0 that name module paths
such as ``"hbjax._model.Hammerstein"`` are read through an alias table), a subclass of :class:`hbjax.AbstractModel` that is
already defined in this process (e.g. a user's extension), or passed in ``classes=``. Models are
rebuilt without calling ``__init__`` (fields set directly, as the dataclass stores them) and then
checked with the classes' ``__check_init__``; any problem raises ``ValueError`` before a model
is returned, so a corrupted file never gives a half-loaded model.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .files import check_readable
from .recording import atomic_write
from .._core.model import AbstractModel

FORMAT = "hbjax-model"
FORMAT_VERSION = 1
_DTYPES = {"float64", "float32", "int64", "int32", "bool"}
# A model saved without 64-bit mode holds float32 coefficients: it loads as it was saved.
_FLOATS = (jnp.float32, jnp.float64)


class ModelFileError(ValueError):
    """A model file that is not valid JSON, not an hbjax model file, or inconsistent.

    Raised by :func:`hbjax.load_model` for every problem with the file's content (syntax,
    foreign or newer format, unknown model types, wrong shapes, integers too large, nesting
    too deep, a polynomial degree beyond the cap); a ``ValueError``, so ``except ValueError``
    catches it too.
    """


# Largest model file read (bytes): a model of any sensible order is far smaller, and the JSON
# parser needs several times the file size in memory.
MAX_FILE_BYTES = 64 * 2**20


def _registered_types() -> dict:
    """Public, stable type names of the model files: hbjax's own model classes by class name.

    Built from the classes themselves (every :class:`hbjax.AbstractModel` subclass defined in an
    hbjax module, plus the blocks it nests), so a new model class is registered by existing.
    """
    from .._core.arx import ARX
    from .._core.backlash import Backlash

    types = {"ARX": ARX, "Backlash": Backlash}
    for cls in _all_subclasses(AbstractModel):
        if cls.__module__.split(".")[0] == "hbjax" and not getattr(cls, "__abstractmethods__", ()):
            types[cls.__name__] = cls
    return types


# Type names written by hbjax 0.1.0 (module paths), read as the registered names they meant.
_LEGACY_MODULES = ("_model", "_backlash", "_arx", "_effects")


def _legacy_alias(class_id: str) -> str | None:
    module, _, name = class_id.rpartition(".")
    if module in {f"hbjax.{m}" for m in _LEGACY_MODULES}:
        return name
    return None


def _class_id(cls) -> str:
    if _registered_types().get(cls.__name__) is cls:
        return cls.__name__
    return f"{cls.__module__}.{cls.__qualname__}"


# ----------------------------------------------------------------------------- encoding


def _encode_float(x: float):
    x = float(x)
    if math.isfinite(x):
        return x
    return {"float": "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")}


def _encode(value, where: str):
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _encode_float(value)
    if isinstance(value, eqx.Module):
        return _encode_module(value, where)
    if isinstance(value, (jax.Array, np.ndarray)):
        if isinstance(value, jax.core.Tracer):
            raise TypeError(f"cannot save a traced array at `{where}` (save outside jit).")
        arr = np.asarray(value)
        dtype = str(arr.dtype)
        if dtype not in _DTYPES:
            raise TypeError(f"cannot save `{where}`: arrays of dtype {dtype} are not supported.")
        flat = arr.reshape(-1).tolist()
        if arr.dtype.kind == "f":
            flat = [_encode_float(x) for x in flat]
        kind = "numpy" if isinstance(value, np.ndarray) else "jax"
        return {"array": flat, "dtype": dtype, "shape": list(arr.shape), "kind": kind}
    if isinstance(value, tuple):
        return {"tuple": [_encode(x, f"{where}[{i}]") for i, x in enumerate(value)]}
    if isinstance(value, list):
        return {"list": [_encode(x, f"{where}[{i}]") for i, x in enumerate(value)]}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError(f"cannot save `{where}`: only dicts with string keys are supported.")
        return {"dict": {k: _encode(x, f"{where}[{k!r}]") for k, x in value.items()}}
    raise TypeError(
        f"cannot save `{where}` of type {type(value).__name__}: model fields must be arrays, "
        "numbers, strings, None, tuples/lists/dicts of these, or hbjax modules."
    )


def _encode_module(module: eqx.Module, where: str) -> dict:
    fields = {}
    for f in dataclasses.fields(module):
        fields[f.name] = _encode(getattr(module, f.name), f"{where}.{f.name}")
    return {"class": _class_id(type(module)), "fields": fields}


def model_to_json(model: AbstractModel) -> str:
    """The model-file text of ``model`` (see the module docstring for the layout)."""
    from .. import __version__

    if not isinstance(model, AbstractModel):
        raise TypeError(
            f"`model` must be an hbjax model (a subclass of hbjax.AbstractModel), got "
            f"{type(model).__name__}."
        )
    doc = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "hbjax_version": __version__,
        "kind": type(model).__name__,
        "model": _encode_module(model, "model"),
    }
    return pretty_json(doc) + "\n"


def _is_scalar(x) -> bool:
    return not isinstance(x, (dict, list)) or (isinstance(x, dict) and set(x) == {"float"})


def pretty_json(obj, depth: int = 0) -> str:
    """JSON with one key per line, but every array entry, list of numbers and matrix row on
    a single line (strict JSON: NaN and inf are refused)."""
    flat = json.dumps(obj, allow_nan=False)
    if _is_scalar(obj) or len(flat) <= 60 or (isinstance(obj, dict) and "array" in obj):
        return flat
    if isinstance(obj, list) and all(_is_scalar(x) for x in obj):
        return flat
    pad, inner = "  " * depth, "  " * (depth + 1)
    if isinstance(obj, list):
        items = [inner + pretty_json(x, depth + 1) for x in obj]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    items = [f"{inner}{json.dumps(k)}: {pretty_json(v, depth + 1)}" for k, v in obj.items()]
    return "{\n" + ",\n".join(items) + "\n" + pad + "}"


def save_model(path, model: AbstractModel, *, overwrite: bool = False) -> pathlib.Path:
    """Save ``model`` to a human-readable JSON model file.

    **Arguments:**

    - `path`: the file to write (conventionally ``*.json``).
    - `model`: any :class:`hbjax.AbstractModel`, e.g. :class:`hbjax.Hammerstein` or an
      extension from the diagnosis; nested modules, arrays and static fields are all saved.
    - `overwrite`: replace an existing file (default: refuse with ``FileExistsError``).

    The file records the package version and the model kind; floats are written exactly, so
    :func:`load_model` gives back a bitwise-equal model. The write is atomic (temporary file
    in the same folder, then rename).

    **Returns:** the path written.
    """
    return atomic_write(path, model_to_json(model), overwrite=overwrite)


# ----------------------------------------------------------------------------- decoding


def _all_subclasses(cls):
    seen, stack = [], [cls]
    while stack:
        c = stack.pop()
        for s in c.__subclasses__():
            if s not in seen:
                seen.append(s)
                stack.append(s)
    return seen


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


def _decode_array(obj, where):
    if set(obj) - {"array", "dtype", "shape", "kind"} or not {"array", "dtype", "shape"} <= set(obj):
        raise ModelFileError(f"`{where}` is a malformed array entry (keys {sorted(obj)}).")
    dtype, shape, data = obj["dtype"], obj["shape"], obj["array"]
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
    arr = np.array(values, dtype=dtype).reshape(shape)
    if obj.get("kind", "jax") == "numpy":
        return arr
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
    expected = [f.name for f in dataclasses.fields(cls)]
    given = obj["fields"]
    missing = [n for n in expected if n not in given]
    unknown = [n for n in given if n not in expected]
    if missing or unknown:
        raise ModelFileError(
            f"`{where}` ({cls.__name__}) does not match the class: missing fields {missing}, "
            f"unknown fields {unknown}."
        )
    _check_degree(cls, given, where)
    values = {n: _decode(given[n], extra, f"{where}.{n}") for n in expected}
    module = object.__new__(cls)
    for name, value in values.items():
        object.__setattr__(module, name, value)
    # The invariants the constructors would have enforced, most-derived class last.
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
                f"`{where}` (Backlash) needs c1, c2 float64 or float32 1-D of equal length >= 1.")
        if not (np.all(np.isfinite(c1)) and np.all(np.isfinite(c2))):
            raise ModelFileError(f"`{where}` (Backlash) has non-finite coefficients.")
    if isinstance(module, ARX):
        a, b = module.a, module.b
        if not (isinstance(a, jax.Array) and isinstance(b, jax.Array) and a.ndim == 1
                and b.ndim == 1 and b.shape[0] >= 1 and a.dtype == b.dtype
                and a.dtype in _FLOATS):
            raise ModelFileError(f"`{where}` (ARX) needs a, b float64 or float32 1-D with nb >= 1.")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ModelFileError(f"`{where}` (ARX) has non-finite coefficients.")


def model_from_json(text: str, *, classes=(), source: str = "<string>") -> AbstractModel:
    """Rebuild a model from model-file text; raises :class:`ModelFileError` on any problem."""
    try:
        return _model_from_json(text, classes, source)
    except RecursionError:
        raise ModelFileError(f"{source}: not a valid JSON model file (nested too deeply).") from None
    except OverflowError as exc:
        raise ModelFileError(f"{source}: a number is too large for its type ({exc}).") from None


def _model_from_json(text, classes, source):
    def constant(name):
        raise ValueError(f"{name} is not a JSON number")

    try:
        doc = json.loads(text, parse_constant=constant)
    except ValueError as exc:  # JSONDecodeError, the digit limit of int(), NaN constants
        raise ModelFileError(f"{source}: not a valid JSON model file ({exc}).") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelFileError(f"{source}: not an hbjax model file (no \"format\": \"{FORMAT}\").")
    version = doc.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= FORMAT_VERSION:
        raise ModelFileError(
            f"{source}: model-file format_version {version!r} is not supported by this hbjax "
            f"(reads 1 to {FORMAT_VERSION}); written by hbjax {doc.get('hbjax_version')!r}."
        )
    if not isinstance(doc.get("model"), dict):
        raise ModelFileError(f"{source}: the `model` entry is missing.")
    try:
        model = _decode_module(doc["model"], tuple(classes), "model")
    except ModelFileError as exc:
        raise ModelFileError(f"{source}: {exc}") from None
    if not isinstance(model, AbstractModel):
        raise ModelFileError(f"{source}: the top-level object is not an hbjax model.")
    if doc.get("kind") != type(model).__name__:
        raise ModelFileError(
            f"{source}: `kind` {doc.get('kind')!r} disagrees with the model class "
            f"{type(model).__name__!r}."
        )
    return model


def load_model(path, *, classes=()) -> AbstractModel:
    """Load a model written by :func:`save_model`.

    **Arguments:**

    - `path`: the model file.
    - `classes`: extra ``eqx.Module`` classes the file may name (user-defined nested modules
      that are not :class:`hbjax.AbstractModel` subclasses). hbjax's own classes and every
      AbstractModel subclass already defined in this process are always accepted.

    **Returns:** the model, bitwise equal to the one saved.

    **Raises:** ``FileNotFoundError``; ``ValueError`` (:class:`ModelFileError`) naming the
    file and the offending entry if the file is corrupted, foreign, from a newer format, or
    names an unknown class. Nothing is returned unless the whole model was rebuilt and checked.
    """
    p = check_readable(path, "model file")
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise ModelFileError(
                f"{p}: larger than {MAX_FILE_BYTES // 2**20} MiB; not an hbjax model file "
                "(models of any sensible order are far smaller)."
            )
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ModelFileError(f"{p}: not a text file; expected an hbjax JSON model file.") from None
    return model_from_json(text, classes=classes, source=str(p))
