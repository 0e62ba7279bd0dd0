"""Numbers in ``repr``: the formatting every hbjax model and result prints through.

:func:`pformat` writes a module, dataclass, dict or array with its numbers, falling back to
shapes (``f64[3]``) for traced values and to a shape plus range for large arrays; a result
code prints as its message. Re-exported by :mod:`hbjax._core.display`.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import numpy as np

from .._misc import is_traced

Z95 = 1.959963984540054  # two-sided 95% normal quantile
MAX_ITEMS = 12  # arrays with more elements print as shape and range


def concrete(x) -> np.ndarray | None:
    """``x`` as a NumPy array, or ``None`` when it is traced (inside jit/vmap/grad)."""
    if x is None or is_traced(x):
        return None
    try:
        return np.asarray(x)
    except Exception:  # abstract values (ShapeDtypeStruct, ...) have no numbers
        return None


def format_number(x, digits: int = 4) -> str:
    """``x`` with ``digits`` significant digits; integers and booleans as themselves."""
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def shape_text(x) -> str:
    return eqx.tree_pformat(x)  # "f64[3]", also for tracers


def format_array(x, digits: int = 4) -> str:
    """Numbers of a small concrete array; shape (and range) otherwise."""
    arr = concrete(x)
    if arr is None or arr.dtype == object:
        return shape_text(x)
    if arr.ndim == 0:
        return format_number(arr.item(), digits)
    if arr.size <= MAX_ITEMS:
        text = np.array2string(arr, separator=", ", max_line_width=10_000,
                               formatter={"all": lambda v: format_number(v, digits)})
        return text.replace("\n", "")
    if arr.size and np.issubdtype(arr.dtype, np.number):
        return f"{shape_text(x)} in [{format_number(np.nanmin(arr))}, {format_number(np.nanmax(arr))}]"
    return shape_text(x)


def is_result_code(x) -> bool:
    # equinox's enumeration items (optimistix/hbjax RESULTS) have no public class name
    return type(x).__name__ == "EnumerationItem" and hasattr(x, "_enumeration")


def format_result_code(item) -> str:
    """A result code as its message (``'successful'``); for a batch, message counts."""
    enum = item._enumeration
    values = concrete(item._value)
    if values is None:
        return f"{enum.__name__}<traced>"
    names = {int(it._value): name for name, it in enum._name_to_item.items()}
    if values.ndim == 0:
        return repr(names.get(int(values), str(int(values))))
    codes, counts = np.unique(values.ravel(), return_counts=True)
    return "{" + ", ".join(f"{names.get(int(c), str(int(c)))!r}: {int(n)}"
                           for c, n in zip(codes, counts)) + "}"


def result_message(item) -> str:
    """The message of a concrete, unbatched result code (``"success"`` when empty)."""
    return item._enumeration[item] or "success"


def _fields(obj):
    if dataclasses.is_dataclass(obj):
        return [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.repr]
    return []


def format_value(x, indent: int, width: int) -> str:
    if is_result_code(x):
        return format_result_code(x)
    if isinstance(x, (jax.Array, np.ndarray, np.generic)):
        return format_array(x)
    if isinstance(x, (bool, int, float)) and not isinstance(x, str):
        return format_number(x) if isinstance(x, float) else repr(x)
    if isinstance(x, dict):
        items = [f"{k!r}: {format_value(v, indent + 2, width)}" for k, v in x.items()]
        return _wrap("{", items, "}", indent, width)
    if isinstance(x, (tuple, list)) and not hasattr(x, "_fields"):
        items = [format_value(v, indent + 2, width) for v in x]
        open_, close = ("(", ")") if isinstance(x, tuple) else ("[", "]")
        if isinstance(x, tuple) and len(x) == 1:
            close = ",)"
        return _wrap(open_, items, close, indent, width)
    if isinstance(x, eqx.Module):  # structurally, so nested lines indent
        items = [f"{k}={format_value(v, indent + 2, width)}" for k, v in _fields(x)]
        return _wrap(f"{type(x).__name__}(", items, ")", indent, width)
    return repr(x)


def _wrap(open_: str, items: list[str], close: str, indent: int, width: int) -> str:
    one = open_ + ", ".join(items) + close
    if len(one) + indent <= width and "\n" not in one:
        return one
    pad = " " * (indent + 2)
    return open_ + "\n" + ",\n".join(pad + i for i in items) + ",\n" + " " * indent + close


def pformat(obj, *, width: int = 88, skip: tuple[str, ...] = ()) -> str:
    """``Name(field=value, ...)`` with numbers: the ``repr`` of hbjax models and results.

    Arrays print their values (shapes when traced, shape and range when large), result
    codes their message, nested modules recursively; lines wrap beyond ``width``.
    `skip` names fields to leave out.
    """
    items = [f"{k}={format_value(v, 2, width)}" for k, v in _fields(obj) if k not in skip]
    return _wrap(f"{type(obj).__name__}(", items, ")", 0, width)
