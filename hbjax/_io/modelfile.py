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
import numpy as np

from .._core.model import AbstractModel
from .._misc import check_bool, is_traced
from .files import atomic_write, check_readable
from .modeldecode import _decode_module
from .modeltypes import (
    _DTYPES, FORMAT, FORMAT_VERSION, MAX_FILE_BYTES, ModelFileError as ModelFileError,
    _class_id,
)


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
        if is_traced(value):
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
    overwrite = check_bool(overwrite, "overwrite")
    return atomic_write(path, model_to_json(model), overwrite=overwrite)


def _checked_classes(classes) -> tuple:
    """``classes`` as a tuple of ``eqx.Module`` subclasses, or a ``TypeError`` naming it."""
    if isinstance(classes, type):
        classes = (classes,)
    if isinstance(classes, (str, bytes)):  # iterable, but its characters are not classes
        raise TypeError("`classes` must be a tuple of eqx.Module subclasses (the classes "
                        f"themselves, not their names), got the string {classes!r}.")
    try:
        out = tuple(classes)
    except TypeError:
        raise TypeError("`classes` must be a tuple of eqx.Module subclasses, got "
                        f"{type(classes).__name__}.") from None
    bad = [c for c in out if not (isinstance(c, type) and issubclass(c, eqx.Module))]
    if bad:
        raise TypeError("`classes` must hold eqx.Module subclasses only, got "
                        f"{bad[0]!r} ({type(bad[0]).__name__}).")
    return out


def model_from_json(text: str, *, classes=(), source: str = "<string>") -> AbstractModel:
    """Rebuild a model from model-file text; raises :class:`ModelFileError` on any problem."""
    classes = _checked_classes(classes)
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
    if not isinstance(version, int) or isinstance(version, bool):
        raise ModelFileError(
            f"{source}: model-file format_version must be an integer (this hbjax reads 1 to "
            f"{FORMAT_VERSION}), got {version!r} ({type(version).__name__}).")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= FORMAT_VERSION:
        raise ModelFileError(
            f"{source}: model-file format_version {version!r} is not supported by this hbjax "
            f"(reads 1 to {FORMAT_VERSION}); written by hbjax {doc.get('hbjax_version')!r}."
        )
    if not isinstance(doc.get("model"), dict):
        raise ModelFileError(f"{source}: the `model` entry is missing.")
    try:
        model = _decode_module(doc["model"], classes, "model")
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
    classes = _checked_classes(classes)  # before the file is opened
    p = check_readable(path, "model file")
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise ModelFileError(
                f"{p}: larger than {MAX_FILE_BYTES // 2**20} MiB; not an hbjax model file "
                "(models of any sensible order are far smaller)."
            )
        text = raw.decode("utf-8-sig")  # (a byte-order mark, as Windows editors save, is read)
    except UnicodeDecodeError:
        raise ModelFileError(f"{p}: not a text file; expected an hbjax JSON model file.") from None
    return model_from_json(text, classes=classes, source=str(p))
