"""What :class:`hbjax.Recording` offers beyond its samples, in the manner of MATLAB's
``iddata``: pandas frames in and out, extra recorded channels, splitting, detrending,
decimation with an anti-alias filter, and a figure.

Plain NumPy; pandas and matplotlib are imported only by the functions that need them.
"""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np

from .._misc import holds_real_numbers
from .csvtable import distinct_columns


@dataclasses.dataclass(frozen=True)
class Trend:
    """What :meth:`hbjax.Recording.detrend` removed: ``offset + slope * t`` for the input
    and the output, ``t`` the recording's time axis (seconds when ``dt`` is known, else
    samples). ``kind`` is ``"mean"`` (slopes 0) or ``"linear"``."""

    kind: str
    v_offset: float
    v_slope: float
    y_offset: float
    y_slope: float

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray]:
        """The removed input and output trends at times ``t``."""
        t = np.asarray(t, np.float64)
        return self.v_offset + self.v_slope * t, self.y_offset + self.y_slope * t

    def restore(self, recording):
        """``recording`` with the trend added back (MATLAB's ``retrend``)."""
        if not hasattr(recording, "t") or not dataclasses.is_dataclass(recording):
            raise TypeError(f"`recording` must be an hbjax.Recording (its times place the "
                            f"trend), got {type(recording).__name__}.")
        v_trend, y_trend = self.evaluate(recording.t)
        return dataclasses.replace(recording, v=recording.v + v_trend, y=recording.y + y_trend,
                                   trend=None)

    def __add__(self, other: "Trend") -> "Trend":
        kind = "linear" if "linear" in (self.kind, other.kind) else "mean"
        return Trend(kind, self.v_offset + other.v_offset, self.v_slope + other.v_slope,
                     self.y_offset + other.y_offset, self.y_slope + other.y_slope)


# A Python float: comparing a huge Python int with it is exact, where float() would overflow.
_MAX = float(np.finfo(np.float64).max)


def _real(x) -> bool:
    # Strings convert with float() and booleans are ints, but neither is a time.
    return not isinstance(x, (bool, np.bool_)) and isinstance(
        x, (int, float, np.integer, np.floating))


def sampling_period(dt) -> float | None:
    """``dt`` as a float: a positive finite number, or ``None`` (unknown)."""
    if dt is None:
        return None
    if not _real(dt):
        raise TypeError(f"`dt` must be a positive float or None, got {dt!r}.")
    val = float(dt) if abs(dt) <= _MAX else np.inf
    if not (np.isfinite(val) and val > 0):
        raise ValueError(f"`dt` must be a positive finite float or None, got {dt!r}.")
    return val


def time_origin(t0) -> float:
    """``t0`` as a float: a finite real number (seconds, or samples without ``dt``)."""
    if not _real(t0):
        raise TypeError(f"`t0` must be a finite real number, got {t0!r}.")
    val = float(t0) if abs(t0) <= _MAX else np.inf
    if not np.isfinite(val):
        raise ValueError(f"`t0` must be a finite real number, got {t0!r}.")
    return val


def check_dt_agrees(dt, step: float, where: str, choose: str) -> float:
    """``dt`` (checked by :func:`sampling_period`) when it agrees with ``step``, the period
    the data themselves give (``where``), to 0.1 % (the jitter of times written with few
    digits). A ``ValueError`` otherwise, saying how to choose: preferring either silently
    would put every later result on a wrong time axis."""
    dt = sampling_period(dt)
    if not abs(dt - step) <= 1e-3 * abs(step):
        raise ValueError(f"`dt`={dt!r} conflicts with {where} ({step:.12g}); {choose}.")
    return dt


def finite_column(x, name: str) -> np.ndarray:
    """A recorded signal as a read-only 1-D finite float64 array; ``name`` as the messages
    give it (a backquoted argument or ``channel 'w'``). Text, objects and complex numbers
    are refused, never parsed or cast to their real part."""
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"{name} must be a numeric array, got {type(x).__name__}.")
    arr = np.asarray(x)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise TypeError(f"{name} must be a numeric array, got dtype {arr.dtype}.")
    if np.iscomplexobj(arr):
        raise TypeError(f"{name} must be real, got complex dtype {arr.dtype}.")
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {arr.shape}.")
    if arr.shape[0] == 0:  # would be written, but not read back, and estimate nothing
        raise ValueError(f"{name} is empty; a recording needs at least one sample.")
    arr = np.array(arr, dtype=np.float64, copy=True)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(
            f"{name} contains NaN or inf ({bad.size} samples, first at index {bad[0]})."
        )
    arr.setflags(write=False)
    return arr


def check_times(rec) -> None:
    """Refuse a recording whose sample times ``t0 + k dt`` overflow float64 (``dt`` near
    1e308): they could be neither written nor used."""
    with np.errstate(over="ignore"):  # an overflow is refused just below
        t = rec.t
    if not np.all(np.isfinite(t)):
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(
            f"the time of sample {k}, t0 + {k} * dt, exceeds the largest float64 "
            f"(`dt` = {rec.dt!r}, `t0` = {rec.t0!r}); rescale the time unit."
        )


def check_channels(channels, n: int) -> types.MappingProxyType:
    """``name -> 1-D finite float64 array of n samples`` (read-only), from a mapping."""
    if channels is None:
        channels = {}
    if not hasattr(channels, "items"):
        raise TypeError(f"`channels` must map names to arrays, got {type(channels).__name__}.")
    out = {}
    for name, x in channels.items():
        if not isinstance(name, str):
            raise TypeError(f"channel names must be strings, got {name!r}.")
        if np.shape(x) != (n,) and not isinstance(x, (str, bytes)) and x is not None:
            raise ValueError(f"channel {name!r} must hold {n} samples like `v`, got shape "
                             f"{np.shape(x)}.")
        out[name] = finite_column(x, f"channel {name!r}")
    return types.MappingProxyType(out)


def take(rec, index):
    """The samples ``index`` (a ``slice`` with step >= 1) as a new recording: channels
    follow, the time origin ``t0`` moves to the first kept sample, ``dt`` scales with the
    step."""
    start, stop, step = index.indices(len(rec))
    if step < 1:
        raise ValueError(f"the slice step must be >= 1, got {step}.")
    dt = None if rec.dt is None else rec.dt * step
    t0 = rec.t0 + start * (1.0 if rec.dt is None else rec.dt)
    channels = {k: x[start:stop:step] for k, x in rec.channels.items()}
    return dataclasses.replace(rec, v=rec.v[start:stop:step], y=rec.y[start:stop:step],
                               channels=channels, dt=dt, t0=t0)


def split(rec, at=0.5):
    """``(first, second)``: the samples before and from ``at``. ``at`` is a fraction in
    (0, 1) of the record (rounded to a sample) or a sample index (an ``int``, negative from
    the end). Both parts keep ``dt`` and their times (the second part's ``t`` continues)."""
    n = len(rec)
    if isinstance(at, bool) or not isinstance(at, (int, float, np.integer, np.floating)):
        raise TypeError(f"`at` must be a fraction in (0, 1) or a sample index, got {at!r}.")
    if isinstance(at, (float, np.floating)):
        if not 0 < at < 1:
            raise ValueError(f"`at` as a fraction must lie in (0, 1), got {at!r}.")
        k = int(round(at * n))
    else:
        k = int(at) + (n if at < 0 else 0)
    if not 0 < k < n:
        raise ValueError(f"`at`={at!r} leaves an empty part of a {n}-sample recording.")
    return take(rec, slice(0, k)), take(rec, slice(k, n))


def _fit_line(t, x, kind):
    if kind == "mean":
        return float(np.mean(x)), 0.0
    tc = t - t.mean()
    slope = float(np.dot(tc, x - x.mean()) / np.dot(tc, tc)) if np.any(tc) else 0.0
    return float(np.mean(x) - slope * t.mean()), slope


def detrend(rec, kind: str = "mean"):
    """A new recording with the input's and the output's mean (``kind="mean"``) or
    least-squares line in time (``kind="linear"``) removed; what was removed is kept in the
    new recording's ``trend`` (a :class:`Trend`, added to any earlier one), so
    ``rec.trend.restore(rec)`` undoes it. Extra channels are left as recorded."""
    if kind not in ("mean", "linear"):
        raise ValueError(f"`kind` must be 'mean' or 'linear', got {kind!r}.")
    t = rec.t
    (va, vb), (ya, yb) = _fit_line(t, rec.v, kind), _fit_line(t, rec.y, kind)
    trend = Trend(kind, va, vb, ya, yb)
    v_trend, y_trend = trend.evaluate(t)
    total = trend if rec.trend is None else rec.trend + trend
    return dataclasses.replace(rec, v=rec.v - v_trend, y=rec.y - y_trend, trend=total)


def lowpass_fir(k: int) -> np.ndarray:
    """The anti-alias filter of :func:`decimate`: a Hamming-windowed sinc of ``20 k + 1``
    taps with cut-off at the new Nyquist frequency and unit gain at DC (the design of
    ``scipy.signal.firwin(20 k + 1, 1 / k)``)."""
    n = 20 * k + 1
    m = np.arange(n) - (n - 1) / 2
    h = np.sinc(m / k) / k * np.hamming(n)
    return h / h.sum()


def zero_phase_filter(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``x`` through the symmetric FIR ``h`` without delay. The ends are extended by odd
    reflection about the end samples (as ``filtfilt`` pads), so a constant or a ramp passes
    unchanged up to the edges instead of being pulled towards zero."""
    half = (h.shape[0] - 1) // 2
    if x.shape[0] < 2:
        return np.convolve(x, h, mode="full")[half:half + x.shape[0]]
    # A record shorter than the filter's half-length is reflected again and again (the
    # odd reflection of a ramp about its end is the ramp's continuation), so the filter
    # never reaches the zeros beyond a single reflection's end.
    xe, pad = x, 0
    while pad < half:
        step = min(half - pad, xe.shape[0] - 1)
        xe = np.concatenate([2 * xe[0] - xe[step:0:-1], xe, 2 * xe[-1] - xe[-2:-step - 2:-1]])
        pad += step
    return np.convolve(xe, h, mode="same")[pad:pad + x.shape[0]]


def decimate(rec, k: int):
    """Every ``k``-th sample after a zero-phase low-pass filter (:func:`lowpass_fir`) that
    removes what would alias above the new Nyquist frequency; ``dt`` becomes ``k dt``.
    Input, output and channels are filtered alike."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"`k` must be a positive integer, got {k!r}.")
    k = int(k)
    if k == 1:
        return rec
    if len(rec) < 2 * k:
        raise ValueError(f"a {len(rec)}-sample recording is too short to decimate by {k}.")
    h = lowpass_fir(k)

    def down(x):
        return zero_phase_filter(x, h)[::k]

    dt = None if rec.dt is None else rec.dt * k
    trend = rec.trend
    if rec.dt is None and trend is not None:
        # without dt the time axis counts samples: the kept sample j, at t0 + j now, was at
        # t0 + k j, so the removed trend is re-expressed on the new axis to restore the same
        # values
        t0 = rec.t0
        trend = Trend(trend.kind, trend.v_offset + trend.v_slope * t0 * (1 - k),
                      trend.v_slope * k, trend.y_offset + trend.y_slope * t0 * (1 - k),
                      trend.y_slope * k)
    return dataclasses.replace(rec, v=down(rec.v), y=down(rec.y), dt=dt, trend=trend,
                               channels={n: down(x) for n, x in rec.channels.items()})


# ----------------------------------------------------------------------------- pandas


def _pandas():
    try:
        import pandas
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError("this needs pandas: `pip install pandas`.") from None
    return pandas


def _column(df, key, role):
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool) and key not in df.columns:
        if not -df.shape[1] <= key < df.shape[1]:
            raise ValueError(f"{role} column index {key} is out of range ({df.shape[1]} columns).")
        return df.columns[key]
    if key not in df.columns:
        raise ValueError(f"no {role} column {key!r}; columns: {list(df.columns)}.")
    return key


def _real_column(df, col, role) -> np.ndarray:
    """A column as float64, refused unless it holds real numbers (integers or floats):
    a complex column would lose its imaginary part, a text column would be parsed."""
    dtype = df[col].dtype
    if not holds_real_numbers(dtype):
        raise TypeError(f"the {role} column {col!r} must hold real numbers, got dtype "
                        f"{dtype}.")
    return df[col].to_numpy(np.float64)


def _index_times(index):
    """Sample times in seconds from a frame's index, or None for a plain 0..N-1 index."""
    pd = _pandas()
    if isinstance(index, pd.RangeIndex):
        return None
    if isinstance(index, pd.DatetimeIndex):
        return (index - index[0]).total_seconds().to_numpy(np.float64)
    if isinstance(index, pd.TimedeltaIndex):
        return index.total_seconds().to_numpy(np.float64)
    if np.issubdtype(index.dtype, np.floating):  # integer indices count samples
        return index.to_numpy(np.float64)
    return None


def uniform_step(t, what: str) -> float:
    steps = np.diff(t)
    step = float(np.median(steps))
    if not step > 0 or np.any(np.abs(steps - step) > 1e-3 * step):
        raise ValueError(f"{what} is not uniformly increasing (median step {step:g}); give `dt`.")
    return step


def from_dataframe(cls, df, *, input, output, channels=None, dt=None, time=None, name=""):
    """A recording from the columns of a pandas ``DataFrame``.

    - `input`, `output`: the columns of ``v`` and ``y`` (names, or positions).
    - `channels`: other columns to keep as extra channels: a list of names, a mapping
      ``new name -> column``, or ``None`` for every remaining numeric column.
    - `dt`: sampling period in seconds. When not given it comes from the `time` column or
      from the frame's index (a numeric, datetime or timedelta index with uniform steps;
      a plain ``0..N-1`` index gives no ``dt``). Given, it replaces the index's spacing, but
      must agree with a `time` column's mean step to 0.1 % (``ValueError`` otherwise).
    """
    pd = _pandas()
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"`df` must be a pandas DataFrame, got {type(df).__name__}.")
    cin, cout = _column(df, input, "input"), _column(df, output, "output")
    ctime = None if time is None else _column(df, time, "time")
    distinct_columns("`df`", {"input": cin, "output": cout, "time": ctime})
    if channels is None:
        used = {cin, cout, ctime}
        channels = {str(c): c for c in df.columns
                    if c not in used and pd.api.types.is_numeric_dtype(df[c])
                    and not pd.api.types.is_bool_dtype(df[c])}
    elif not hasattr(channels, "items"):
        channels = {str(c): c for c in channels}
    cols = {n: _real_column(df, _column(df, c, "channel"), "channel")
            for n, c in channels.items()}
    t0 = 0.0
    t = _real_column(df, ctime, "time") if ctime is not None else _index_times(df.index)
    if t is None and ctime is None and dt is None and df.index.name == "sample" \
            and np.issubdtype(df.index.dtype, np.integer) and len(df.index):
        # a frame of to_dataframe without dt: its index counts samples from the record's t0
        t0 = float(df.index[0])
    if t is not None and len(t) >= 2:
        t0 = float(t[0])
        if dt is None:
            dt = uniform_step(t, f"the {'time column' if ctime is not None else 'index'}")
            # A frame of to_dataframe carries its recording's exact period: the index's
            # steps, differences of rounded times, are that period only up to rounding.
            kept = df.attrs.get("dt") if ctime is None else None
            if isinstance(kept, float) and math.isfinite(kept) and kept > 0 \
                    and abs(kept - dt) <= 1e-9 * kept:
                dt = kept
        elif ctime is not None:  # (a given dt does replace an index's spacing)
            dt = check_dt_agrees(dt, (t[-1] - t[0]) / (len(t) - 1),
                                 f"the step of the time column {time!r}",
                                 "give only one of them: leave out `dt` to use the times, "
                                 "or `time` to use `dt`")
    return cls(v=_real_column(df, cin, "input"), y=_real_column(df, cout, "output"), dt=dt,
               source="DataFrame", name=str(name), channels=cols, t0=t0)


def to_dataframe(rec):
    """Columns ``v``, ``y`` and the channels; the index is ``t`` (seconds) when ``dt`` is
    known, else ``sample``."""
    pd = _pandas()
    for taken in ("v", "y"):
        if taken in rec.channels:
            role = "input" if taken == "v" else "output"
            raise ValueError(f"channel name {taken!r} is the frame's {role} column: rename "
                             f"the channel (`channels`) before to_dataframe.")
    data = {"v": rec.v, "y": rec.y, **dict(rec.channels)}
    name = "t" if rec.dt is not None else "sample"
    index = pd.Index(rec.t if rec.dt is not None else rec.t.astype(np.int64), name=name)
    frame = pd.DataFrame(data, index=index)
    if rec.dt is not None:  # for from_dataframe: the exact period, not the index's steps
        frame.attrs["dt"] = float(rec.dt)
    return frame
