"""Argument checks of the figures in :mod:`hbjax.plot`, run on entry: a wrong argument is
named there, with what was expected, rather than failing deep inside matplotlib with an
attribute or shape error, or drawing an empty plot."""

import functools

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import FigureBase

from .._core.backlash import Backlash
from .._misc import as_float_array, is_real_scalar


def closes_on_error(figure_function):
    """Wrap a figure function so that a figure it opened is closed again when it raises
    (a matplotlib argument it passes through, such as a colour, is checked only while
    drawing): a failed call leaves no half-drawn figure open in pyplot, to reappear at the
    next ``plt.show()`` or to accumulate in a notebook."""

    @functools.wraps(figure_function)
    def drawn(*args, **kwargs):
        before = set(plt.get_fignums())
        try:
            return figure_function(*args, **kwargs)
        except BaseException:
            for number in set(plt.get_fignums()) - before:
                plt.close(number)
            raise

    return drawn


def instance(x, cls, name: str, what: str):
    """``x`` if it is a ``cls``, else a ``TypeError`` saying `name` must be `what`."""
    if not isinstance(x, cls):
        raise TypeError(f"`{name}` must be {what}, got {type(x).__name__}.")
    return x


def backlash(x, name: str = "backlash") -> Backlash:
    """A :class:`hbjax.Backlash`; for a model holding one (a Hammerstein) the message says
    to pass its ``.backlash``."""
    if isinstance(x, Backlash):
        return x
    hint = " (pass the model's `.backlash`)" if isinstance(getattr(x, "backlash", None),
                                                           Backlash) else ""
    raise TypeError(f"`{name}` must be an hbjax.Backlash, got {type(x).__name__}{hint}.")


def _real(x):
    """``x`` as a float if it is a real number (a NumPy or JAX 0-d array included), else
    ``None``."""
    if is_real_scalar(x):
        return float(x)
    arr = np.asarray(x) if hasattr(x, "dtype") else None
    if arr is not None and arr.ndim == 0 and arr.dtype.kind in "iuf":
        return float(arr)
    return None


def interval(x, name: str) -> tuple[float, float]:
    """``(lo, hi)``: two finite real numbers with ``lo < hi``."""
    ends = [_real(b) for b in x] if isinstance(x, (tuple, list, np.ndarray)) else []
    if len(ends) != 2 or None in ends:
        raise TypeError(f"`{name}` must be a pair (lo, hi) of real numbers, got {x!r}.")
    lo, hi = ends
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"`{name}` must be (lo, hi) with finite lo < hi, got {x!r}.")
    return lo, hi


def window(x, n: int, name: str = "window") -> tuple[int, int]:
    """``(start, stop)`` samples of a record of ``n``: integers with
    ``0 <= start < stop <= n`` (``None``: the whole record)."""
    if x is None:
        return 0, n
    ends = list(x) if isinstance(x, (tuple, list, np.ndarray)) else []
    if len(ends) != 2 or not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool)
                                 for k in ends):
        raise TypeError(f"`{name}` must be None or a pair (start, stop) of sample indices, "
                        f"got {x!r}.")
    start, stop = int(ends[0]), int(ends[1])
    if not 0 <= start < stop <= n:
        raise ValueError(f"`{name}` must satisfy 0 <= start < stop <= {n} (the record's "
                         f"samples), got {x!r}.")
    return start, stop


def axes(x, name: str, count: int | None = None):
    """``None``, or matplotlib axes to draw in: one ``Axes`` (``count=None``), else a
    sequence (or array, as ``plt.subplots`` returns) of exactly ``count``; returned as a
    list."""
    if x is None:
        return None
    if count is None:
        return instance(x, Axes, name, "None or a matplotlib Axes")
    what = f"None or a sequence of {count} matplotlib Axes"
    if not isinstance(x, (tuple, list, np.ndarray)):
        raise TypeError(f"`{name}` must be {what}, got {type(x).__name__}.")
    items = list(np.ravel(np.asarray(x, dtype=object))) if isinstance(x, np.ndarray) else list(x)
    for item in items:
        instance(item, Axes, name, what)
    if len(items) != count:
        raise ValueError(f"`{name}` must be {what}, got {len(items)} Axes.")
    return items


def figure(x, name: str = "fig"):
    """``None`` or a matplotlib figure (or subfigure) to draw in."""
    return x if x is None else instance(x, FigureBase, name, "None or a matplotlib Figure")


def output(x, name: str) -> np.ndarray:
    """A record to draw: a non-empty 1-D real array (non-finite samples are gaps)."""
    arr = np.asarray(as_float_array(x, name, ndim=1, host=True))
    if arr.shape[0] == 0:
        raise ValueError(f"`{name}` must hold at least one sample, got an empty array.")
    return arr
