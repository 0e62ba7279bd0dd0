"""What a model file may name: the format tag, the registered public type names (built from
hbjax's own model classes), the aliases of files written by hbjax 0.1.0 and the error every
problem with a model file raises."""

from __future__ import annotations

import jax.numpy as jnp

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


def _all_subclasses(cls):
    seen, stack = [], [cls]
    while stack:
        c = stack.pop()
        for s in c.__subclasses__():
            if s not in seen:
                seen.append(s)
                stack.append(s)
    return seen
