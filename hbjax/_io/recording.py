"""Recordings in and out: the :class:`Recording` record, CSV/NPZ/JSON readers, a CSV writer,
and the atomic no-clobber file writer every hbjax writer goes through.

Readers parse in plain Python/NumPy (no JAX) and report bad input by file, row and column, so
a researcher can open the file at the offending cell: rows are counted 1-based as a text editor
shows them (the header is row 1), columns by their header name when there is one.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import pathlib
import re

import numpy as np

from .files import atomic_write as atomic_write, check_readable

from . import frames as _frames

# Column names of the BRFD JSON layout (banded rotary friction device, see hbjax/data/README.md).
BRFD_COLUMNS = (
    "time",
    "displacement",
    "friction force",
    "velocity",
    "actuator force 1",
    "actuator force 2",
)


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """One input/output record: input ``v`` and output ``y`` sampled at the same instants.

    **Fields:**

    - `v`: input samples, 1-D float64 NumPy array (read-only).
    - `y`: output samples, same length as `v` (read-only).
    - `dt`: sampling period in seconds, or ``None`` when unknown.
    - `source`: where the record came from (a path, or ``hbjax.datasets:<name>``).
    - `name`: a short label (file stem or data-set name).
    - `channels`: other signals recorded at the same instants, ``name -> array`` (e.g. the
      BRFD's velocity and actuator forces); read-only, empty by default.
    - `t0`: time of the first sample (seconds, or samples when ``dt`` is ``None``).
    - `trend`: what :meth:`detrend` removed (``None`` if nothing).

    The arrays are finite; a record with NaN or inf is refused at construction.
    Like MATLAB's ``iddata``: :meth:`from_dataframe` / :meth:`to_dataframe`, :meth:`split`,
    :meth:`detrend`, :meth:`decimate`, :meth:`plot`; :func:`hbjax.fit`, :func:`hbjax.refine`
    and :func:`hbjax.diagnose` accept a recording wherever they take ``(v, y)``.
    """

    v: np.ndarray
    y: np.ndarray
    dt: float | None = None
    source: str = ""
    name: str = ""
    channels: dict = dataclasses.field(default_factory=dict)
    t0: float = 0.0
    trend: _frames.Trend | None = None

    def __post_init__(self):
        v = _finite_column(self.v, "v")
        y = _finite_column(self.y, "y")
        if v.shape != y.shape:
            raise ValueError(
                f"`v` and `y` must have equal lengths, got {v.shape[0]} and {y.shape[0]} samples."
            )
        dt = self.dt
        if dt is not None:
            if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating, np.integer)):
                raise TypeError(f"`dt` must be a positive float or None, got {dt!r}.")
            dt = float(dt)
            if not (np.isfinite(dt) and dt > 0):
                raise ValueError(f"`dt` must be a positive finite float or None, got {dt!r}.")
        object.__setattr__(self, "v", v)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "channels", _frames.check_channels(self.channels, v.shape[0]))
        object.__setattr__(self, "t0", float(self.t0))

    def __len__(self) -> int:
        return int(self.v.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Sample times ``t0 + k * dt`` (seconds), or sample indices ``t0 + k`` when ``dt``
        is ``None``."""
        k = np.arange(len(self), dtype=np.float64)
        return self.t0 + (k if self.dt is None else k * self.dt)

    def slice(self, start: int | None = None, stop: int | None = None) -> "Recording":
        """The samples ``start:stop`` as a new record (same ``dt``, ``source`` and ``name``;
        channels sliced alike, times kept)."""
        return _frames.take(self, slice(start, stop))

    @classmethod
    def from_dataframe(cls, df, *, input, output, channels=None, dt=None, time=None,
                       name: str = "") -> "Recording":
        """A recording from a pandas ``DataFrame``: `input`, `output` name its columns;
        `channels` the extra ones (default every other numeric column); `dt` comes from
        the `time` column or a uniform time index when not given."""
        return _frames.from_dataframe(cls, df, input=input, output=output, channels=channels,
                                      dt=dt, time=time, name=name)

    def to_dataframe(self):
        """A pandas ``DataFrame`` with columns ``v``, ``y`` and the channels, indexed by
        ``t`` (seconds) when ``dt`` is known."""
        return _frames.to_dataframe(self)

    def split(self, at=0.5) -> tuple["Recording", "Recording"]:
        """``(estimation, validation)`` parts before and from `at`: a fraction in (0, 1) or
        a sample index. Both keep ``dt`` and their times."""
        return _frames.split(self, at)

    def detrend(self, kind: str = "mean") -> "Recording":
        """Input and output less their mean (``"mean"``) or straight line in time
        (``"linear"``); the removed trend is kept in ``trend`` (``trend.restore`` adds it back)."""
        return _frames.detrend(self, kind)

    def decimate(self, k: int) -> "Recording":
        """Every `k`-th sample after a zero-phase anti-alias low-pass filter (FIR, cut-off
        at the new Nyquist frequency); ``dt`` becomes ``k dt``."""
        return _frames.decimate(self, k)

    def plot(self, **kwargs):
        """Input, output and channels against time (seconds when ``dt`` is known); see
        :func:`hbjax.plot.plot_recording`."""
        from .._plot.recording import plot_recording  # matplotlib only when plotting

        return plot_recording(self, **kwargs)

    def __repr__(self) -> str:
        dt = "None" if self.dt is None else f"{self.dt:g}"
        extra = f", channels={list(self.channels)}" if self.channels else ""
        return (f"Recording(name={self.name!r}, samples={len(self)}, dt={dt}, "
                f"source={self.source!r}{extra})")


def _finite_column(x, name: str) -> np.ndarray:
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"`{name}` must be a numeric array, got {type(x).__name__}.")
    arr = np.asarray(x)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise TypeError(f"`{name}` must be a numeric array, got dtype {arr.dtype}.")
    if np.iscomplexobj(arr):
        raise TypeError(f"`{name}` must be real, got complex dtype {arr.dtype}.")
    if arr.ndim != 1:
        raise ValueError(f"`{name}` must be a 1-D array, got shape {arr.shape}.")
    arr = np.array(arr, dtype=np.float64, copy=True)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(
            f"`{name}` contains NaN or inf ({bad.size} samples, first at index {bad[0]})."
        )
    arr.setflags(write=False)
    return arr


# ----------------------------------------------------------------------------- reading


def load_recording(
    path,
    *,
    input: int | str | None = None,
    output: int | str | None = None,
    time: int | str | None = None,
    dt: float | None = None,
) -> Recording:
    """Read an input/output record from a CSV, ``.npz`` or BRFD-layout ``.json`` file.

    **Arguments:**

    - `path`: the file. The format follows the suffix: ``.npz``, ``.json``, anything else CSV.
    - `input`, `output`: the columns holding ``v`` and ``y``, by header name or 0-based index.
      Defaults: CSV columns ``v`` and ``y`` when the header names both (the layout
      :func:`save_recording` writes), else columns 0 and 1; NPZ arrays ``v`` and ``y`` if
      present, else the first two arrays; BRFD JSON columns ``displacement`` (1) and
      ``friction force`` (2).
    - `time`: optional column of sample times; ``dt`` is their (uniform) spacing. Times
      written as ``k * dt`` give back ``dt`` exactly.
    - `dt`: the sampling period, when the file does not give it.

    The file's own sampling period is used when no `time` or `dt` is given: the
    ``# hbjax recording; dt = ...`` comment line of a CSV file written by
    :func:`save_recording`, the ``dt`` entry of an NPZ archive or a BRFD JSON file.

    CSV files may have a header row (detected: a first row with a non-numeric cell) and
    blank or ``#`` comment lines; the delimiter is a comma, semicolon, tab or whitespace.
    Cells are plain decimal numbers (``1.5``, ``-2e-3``); ``1_000`` or non-ASCII digits are
    refused as non-numeric.
    Unused columns may hold anything (e.g. blank cells). Errors (``ValueError``) name the
    file, row and column of a missing column, a non-numeric or empty cell, a ragged row, a
    NaN or an empty file.

    **Returns:** a :class:`hbjax.Recording` with ``source`` the path and ``name`` its stem.
    """
    p = check_readable(path, "recording file")
    suffix = p.suffix.lower()
    t0, channels = 0.0, {}
    if suffix == ".npz":
        columns, file_dt, t0, channels = _read_npz(p, input, output, time)
    elif suffix == ".json":
        columns, file_dt = _read_brfd_json(p, input, output, time)
    else:
        table = read_csv_table(p)
        v_col, y_col = table.default_columns()
        keys = [input if input is not None else v_col, output if output is not None else y_col,
                time]
        columns = table.columns(keys, ("input", "output", "time"))
        file_dt = table.dt
        if table.meta is not None:  # written by save_recording: its t0 and channels too
            t0 = table.meta.get("t0", 0.0)
            used = {table.index(k, "column") for k in keys if k is not None}
            used |= {j for j in [table.named("t")] if j is not None}
            channels = {table.header[j].strip(): table.column(j)
                        for j in range(table.n_columns) if j not in used}
    v, y, t = columns
    rec_dt = _resolve_dt(p, t, file_dt, dt)
    if t is not None:
        t0 = float(t[0])
    try:
        return Recording(v=v, y=y, dt=rec_dt, source=str(p), name=p.stem, channels=channels,
                         t0=t0)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{p}: {exc}") from None


def _resolve_dt(p, t, file_dt, dt):
    if dt is not None:
        return dt
    if t is not None:
        # The file's own dt when its times are exactly t0 + k * dt (save_recording's layout).
        if file_dt is not None and np.array_equal(t[0] + np.arange(t.shape[0]) * file_dt, t):
            return file_dt
        return _uniform_step(t, p)
    return file_dt


def _uniform_step(t: np.ndarray, p) -> float:
    n = t.shape[0]
    if n < 2:
        raise ValueError(
            f"{p}: the time column needs at least 2 samples to give `dt` (pass dt=...)."
        )
    # Times written as t0 + k * dt (as save_recording writes them) give dt exactly.
    step = float(t[1] - t[0])
    if step > 0 and np.array_equal(t[0] + np.arange(n) * step, t):
        return step
    steps = np.diff(t)
    # Otherwise the mean step, to 12 significant digits (decimal times such as 0.1, 0.2, 0.3
    # then give dt = 0.1, not 0.09999999999999998).
    span = (float(t[-1]) - float(t[0])) / (n - 1)
    step = float(f"{span:.12g}") if math.isfinite(span) else span
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"{p}: the time column must increase, got mean step {step!r}.")
    # Times written with few digits jitter; a 0.1 % tolerance accepts that but not gaps.
    bad = np.flatnonzero(np.abs(steps - step) > 1e-3 * step)
    if bad.size:
        raise ValueError(
            f"{p}: the time column is not uniformly sampled (step {step:g}, but "
            f"{steps[bad[0]]:g} between data rows {bad[0] + 1} and {bad[0] + 2})."
        )
    return step


class CsvTable:
    """Cells of a CSV file as strings, with their 1-based line numbers (for error messages)."""

    def __init__(self, path, header, rows, lines, meta=None):
        self.path, self.header, self.rows, self.lines = path, header, rows, lines
        # From a "# hbjax recording; dt = ...; t0 = ..." comment line (save_recording's
        # layout), else None.
        self.meta = meta

    @property
    def dt(self) -> float | None:
        return None if self.meta is None else self.meta.get("dt")

    def named(self, name: str) -> int | None:
        """Index of the header column called exactly ``name`` (stripped), else None."""
        if self.header is None:
            return None
        names = [h.strip() for h in self.header]
        return names.index(name) if name in names else None

    def default_columns(self) -> tuple[int, int]:
        """Input and output columns when none are asked for: ``v`` and ``y`` by name when
        the header has both (the layout :func:`save_recording` writes, ``t,v,y``), else the
        first two columns."""
        v, y = self.named("v"), self.named("y")
        if v is not None and y is not None:
            return v, y
        return 0, 1

    @property
    def n_columns(self) -> int:
        return len(self.header) if self.header is not None else len(self.rows[0])

    def index(self, key, role: str) -> int:
        """Column index of ``key`` (header name or 0-based integer)."""
        if isinstance(key, bool):
            raise TypeError(f"`{role}` must be a column name or index, got {key!r}.")
        if isinstance(key, (int, np.integer)):
            if not -self.n_columns <= key < self.n_columns:
                raise ValueError(
                    f"{self.path}: {role} column index {key} is out of range; the file has "
                    f"{self.n_columns} columns{self._names()}."
                )
            return int(key) % self.n_columns
        if isinstance(key, str):
            if self.header is None:
                if key.strip().lstrip("-").isdigit():
                    return self.index(int(key), role)
                raise ValueError(
                    f"{self.path}: {role} column {key!r} asked by name, but the file has no "
                    "header row; give a 0-based column index."
                )
            names = [h.strip() for h in self.header]
            if key.strip() in names:
                return names.index(key.strip())
            if key.strip().lstrip("-").isdigit():
                return self.index(int(key), role)
            raise ValueError(f"{self.path}: no {role} column named {key!r}{self._names()}.")
        raise TypeError(f"`{role}` must be a column name or index, got {type(key).__name__}.")

    def _names(self) -> str:
        if self.header is None:
            return ""
        return " (columns: " + ", ".join(repr(h.strip()) for h in self.header) + ")"

    def column_label(self, j: int) -> str:
        if self.header is not None and self.header[j].strip():
            return f"column {j} ({self.header[j].strip()!r})"
        return f"column {j}"

    def column(self, j: int) -> np.ndarray:
        out = np.empty(len(self.rows), dtype=np.float64)
        for r, (row, line) in enumerate(zip(self.rows, self.lines)):
            cell = row[j].strip()
            try:
                out[r] = parse_number(cell)
            except ValueError:
                what = "empty cell" if not cell else f"non-numeric cell {cell!r}"
                raise ValueError(
                    f"{self.path}: {what} at row {line}, {self.column_label(j)}."
                ) from None
            if not np.isfinite(out[r]):
                raise ValueError(
                    f"{self.path}: {cell!r} (not finite) at row {line}, {self.column_label(j)}."
                )
        return out

    def columns(self, keys, roles):
        """The float columns ``keys`` (``None`` entries give ``None``), all checked."""
        idx = [None if k is None else self.index(k, role) for k, role in zip(keys, roles)]
        return [None if j is None else self.column(j) for j in idx]


# A decimal number as written by people and programs: ASCII digits, optional sign, point and
# exponent, or inf/nan. Python's float() also takes "1_000" and non-ASCII digits ("１２");
# those are refused as non-numeric so that a cell is never read as a number it does not show.
_NUMBER = re.compile(
    r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf|infinity|nan)", re.ASCII | re.IGNORECASE
)


def parse_number(cell: str) -> float:
    """``float(cell)`` for a plain decimal number only; ``ValueError`` otherwise."""
    text = cell.strip()
    if not _NUMBER.fullmatch(text):
        raise ValueError(f"not a number: {cell!r}")
    return float(text)


# The comment line save_recording writes above the header, with the exact sampling period
# and time origin when they are known: "# hbjax recording; dt = 0.1; t0 = 0.0".
_META_COMMENT = re.compile(r"#\s*hbjax recording\s*((?:;\s*\w+\s*=\s*\S+\s*)*)$")
_META_KEYS = ("dt", "t0")


def _split_row(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return next(csv.reader([line], delimiter=delimiter))


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_csv_table(path) -> CsvTable:
    """Parse a delimited text file into a :class:`CsvTable`, refusing empty and ragged files."""
    p = pathlib.Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a text (UTF-8) file; expected CSV.") from None
    lines = text.splitlines()
    numbered = [
        (i + 1, line)
        for i, line in enumerate(lines)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    meta = None
    for i, line in enumerate(lines):
        match = _META_COMMENT.match(line.strip())
        if match:
            meta = _parse_meta(match.group(1), f"{p}: row {i + 1}")
            break
        if line.strip() and not line.lstrip().startswith("#"):
            break  # the comment sits above the header
    if not numbered:
        raise ValueError(f"{p}: the file is empty (no header and no data rows).")
    first = numbered[0][1]
    delimiter = next((d for d in (",", ";", "\t") if d in first), None)
    rows = [(n, _split_row(line, delimiter)) for n, line in numbered]
    header = None
    if not all(_is_number(c) for c in rows[0][1] if c.strip()) or not any(
        c.strip() for c in rows[0][1]
    ):
        header = rows[0][1]
        rows = rows[1:]
    if not rows:
        raise ValueError(f"{p}: the file has a header row but no data rows.")
    width = len(header) if header is not None else len(rows[0][1])
    for n, cells in rows:
        if len(cells) != width:
            raise ValueError(
                f"{p}: ragged row {n}: {len(cells)} cells, but the "
                f"{'header' if header is not None else 'first row'} has {width}."
            )
    return CsvTable(p, header, [c for _, c in rows], [n for n, _ in rows], meta)


def _parse_meta(text: str, where: str) -> dict:
    meta = {}
    for item in text.split(";")[1:]:
        key, _, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if key not in _META_KEYS:
            continue  # written by a newer hbjax: ignored
        try:
            meta[key] = parse_number(value)
        except ValueError:
            raise ValueError(f"{where}: `{key}` = {value!r} is not a number.") from None
    return meta


def _read_npz(p, input, output, time):
    try:
        archive = np.load(p, allow_pickle=False)
    except Exception as exc:  # zip errors, bad magic, pickled objects
        raise ValueError(f"{p}: not a readable .npz archive ({exc}).") from None
    with archive:
        names = list(archive.files)
        if not names:
            raise ValueError(f"{p}: the archive is empty.")
        if input is None:
            input = "v" if "v" in names else 0
        if output is None:
            output = "y" if "y" in names else 1
        if time is None and "t" in names and {"v", "y"} <= set(names):
            time = None  # times are only used when asked for; dt below covers the usual case

        def get(key, role):
            if key is None:
                return None
            if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
                if not -len(names) <= key < len(names):
                    raise ValueError(
                        f"{p}: {role} array index {key} is out of range; arrays: {names}."
                    )
                key = names[key]
            if key not in names:
                raise ValueError(f"{p}: no {role} array named {key!r}; arrays: {names}.")
            arr = _npz_array(archive, key, p)
            if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.number):
                raise ValueError(
                    f"{p}: array {key!r} must be a 1-D numeric array, got shape {arr.shape} "
                    f"dtype {arr.dtype}."
                )
            if np.iscomplexobj(arr):
                raise ValueError(f"{p}: array {key!r} must be real, got dtype {arr.dtype}.")
            arr = arr.astype(np.float64)
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise ValueError(f"{p}: array {key!r} has NaN or inf at index {bad[0]}.")
            return arr

        cols = [get(input, "input"), get(output, "output"), get(time, "time")]
        file_dt = None
        if "dt" in names:
            raw = _npz_array(archive, "dt", p)
            if (raw.size != 1 or raw.dtype == bool or not np.issubdtype(raw.dtype, np.number)
                    or np.iscomplexobj(raw)):
                raise ValueError(
                    f"{p}: array 'dt' must hold one real number (the sampling period), got "
                    f"shape {raw.shape} dtype {raw.dtype}."
                )
            file_dt = float(raw.reshape(()))
        t0 = 0.0
        if "t0" in names:
            raw = _npz_array(archive, "t0", p)
            if raw.shape != () or raw.dtype != np.float64:
                raise ValueError(f"{p}: array 't0' must be a float64 scalar, got shape "
                                 f"{raw.shape} dtype {raw.dtype}.")
            t0 = float(raw)
        channels = {}
        if "channel_names" in names or "channels" in names:
            channels = _npz_channels(archive, p, cols[0].shape[0])
    if cols[0].shape != cols[1].shape:
        raise ValueError(
            f"{p}: input and output arrays differ in length ({cols[0].shape[0]} and "
            f"{cols[1].shape[0]})."
        )
    return cols, file_dt, t0, channels


def _npz_channels(archive, p, n: int) -> dict:
    """The channels save_recording stores: ``channel_names`` (1-D text) and ``channels``
    (2-D float64, one row per name)."""
    if not {"channel_names", "channels"} <= set(archive.files):
        raise ValueError(f"{p}: arrays 'channel_names' and 'channels' come together.")
    names = _npz_array(archive, "channel_names", p)
    data = _npz_array(archive, "channels", p)
    if names.ndim != 1 or names.dtype.kind != "U":
        raise ValueError(f"{p}: array 'channel_names' must be 1-D text, got shape {names.shape} "
                         f"dtype {names.dtype}.")
    if data.dtype != np.float64 or data.shape != (names.shape[0], n):
        raise ValueError(f"{p}: array 'channels' must be float64 of shape "
                         f"({names.shape[0]}, {n}), got shape {data.shape} dtype {data.dtype}.")
    if len(set(names.tolist())) != names.shape[0]:
        raise ValueError(f"{p}: array 'channel_names' repeats a name.")
    return {str(name): data[k] for k, name in enumerate(names.tolist())}


def _npz_array(archive, key, p) -> np.ndarray:
    try:
        return archive[key]
    except Exception as exc:  # a damaged member: zlib/zip/format errors
        raise ValueError(f"{p}: array {key!r} cannot be read ({exc}).") from None


def read_json_text(text: str, source) -> object:
    """``json.loads`` with every failure a ``ValueError`` naming ``source``: syntax, the
    NaN/Infinity extensions (not JSON), integers too long to read, nesting too deep."""

    def constant(name):
        raise ValueError(f"{name} is not a JSON number")

    try:
        return json.loads(text, parse_constant=constant)
    except RecursionError:
        raise ValueError(f"{source}: not valid JSON (nested too deeply).") from None
    except ValueError as exc:  # JSONDecodeError, digit limit of int(), NaN constants
        raise ValueError(f"{source}: not valid JSON ({exc}).") from None


def _read_brfd_json(p, input, output, time):
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc}).") from None
    doc = read_json_text(text, p)
    if not isinstance(doc, dict) or not isinstance(doc.get("data"), list):
        raise ValueError(
            f"{p}: expected the BRFD JSON layout, an object with a `data` list of rows."
        )
    rows = doc["data"]
    if not rows:
        raise ValueError(f"{p}: `data` holds no rows.")
    width = len(rows[0]) if isinstance(rows[0], list) else -1
    for r, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != width:
            raise ValueError(f"{p}: ragged row {r} in `data` (expected {width} numbers).")

    def index(key, role):
        if key is None:
            return None
        if isinstance(key, str):
            if key in BRFD_COLUMNS[:width]:
                return BRFD_COLUMNS.index(key)
            if key.strip().lstrip("-").isdigit():
                key = int(key)
            else:
                raise ValueError(
                    f"{p}: no {role} column named {key!r}; columns: {list(BRFD_COLUMNS[:width])}."
                )
        if not -width <= key < width:
            raise ValueError(f"{p}: {role} column index {key} is out of range (width {width}).")
        return int(key) % width

    idx = [
        index(1 if input is None else input, "input"),
        index(2 if output is None else output, "output"),
        index(time, "time"),
    ]
    cols = []
    for j, role in zip(idx, ("input", "output", "time")):
        if j is None:
            cols.append(None)
            continue
        col = np.empty(len(rows))
        for r, row in enumerate(rows):
            cell = row[j]
            if isinstance(cell, bool) or not isinstance(cell, (int, float)):
                raise ValueError(
                    f"{p}: non-numeric value {_short(cell)} at data row {r}, column {j}."
                )
            try:
                col[r] = cell
            except OverflowError:
                raise ValueError(
                    f"{p}: number too large for a float64 at data row {r}, column {j}."
                ) from None
            if not np.isfinite(col[r]):
                raise ValueError(f"{p}: NaN or inf at data row {r}, column {j}.")
        cols.append(col)
    file_dt = doc.get("dt")
    if file_dt is not None and (isinstance(file_dt, bool) or not isinstance(file_dt, (int, float))):
        raise ValueError(f"{p}: `dt` must be a number, got {_short(file_dt)}.")
    if file_dt is not None:
        try:
            file_dt = float(file_dt)
        except OverflowError:
            raise ValueError(f"{p}: `dt` is too large for a float64.") from None
    return cols, file_dt


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


# ----------------------------------------------------------------------------- writing


def format_float(x: float) -> str:
    """Shortest decimal that reads back to the same float64 (``repr``)."""
    return repr(float(x))


def save_recording(path, recording: Recording, *, overwrite: bool = False) -> pathlib.Path:
    """Write ``recording`` to a file that :func:`load_recording` reads back bit for bit:
    ``v``, ``y``, ``dt``, ``t0`` and the channels (not ``trend``).

    - ``*.npz``: arrays ``v``, ``y``, ``t0`` (0-d), ``dt`` (0-d, when known) and, with
      channels, ``channel_names`` and ``channels`` (one row each).
    - anything else but ``*.json``: CSV. A comment line ``# hbjax recording; dt = <dt>;
      t0 = <t0>`` (entries when known), then header ``v,y`` or, when ``dt`` is known,
      ``t,v,y`` with times ``t0 + k * dt``, then one column per channel. Values are written
      with the shortest exact decimal, so the same float64 numbers are read back, by default
      or through ``time="t"``. Channel names must be non-empty, free of line breaks and of
      surrounding blanks, and not ``t``, ``v`` or ``y``.
    - ``*.json`` is refused: that suffix is read as the BRFD layout.

    Times that overflow float64 (``dt`` near 1e308) are refused rather than written as
    ``inf``. Atomic, and an existing file is kept unless ``overwrite``.
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"`recording` must be an hbjax.Recording, got {type(recording).__name__}.")
    suffix = pathlib.Path(path).suffix.lower()
    if suffix == ".json":
        raise ValueError(
            f"{str(path)!r}: save_recording writes CSV or .npz; a .json file would be read back "
            "as the BRFD layout. Choose a .csv or .npz name."
        )
    with np.errstate(over="ignore"):  # an overflow is refused just below
        t = recording.t
    if not np.all(np.isfinite(t)):
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(
            f"the time of sample {k}, t0 + {k} * dt, exceeds the largest float64 "
            f"(`dt` = {recording.dt!r}, `t0` = {recording.t0!r}); rescale the time unit."
        )
    names = list(recording.channels)
    if suffix == ".npz":
        arrays = {"v": recording.v, "y": recording.y,
                  "t0": np.asarray(recording.t0, dtype=np.float64)}
        if recording.dt is not None:
            arrays["dt"] = np.asarray(recording.dt, dtype=np.float64)
        if names:
            arrays["channel_names"] = np.array(names, dtype=str)
            arrays["channels"] = np.stack([recording.channels[n] for n in names])
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        return atomic_write(path, buf.getvalue(), overwrite=overwrite)
    for name in names:
        if (not name or name != name.strip() or name in ("t", "v", "y")
                or any(c in name for c in "\r\n\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")):
            raise ValueError(
                f"channel name {name!r} cannot be a CSV column name (empty, blanks around it, "
                "a line break, or t/v/y); save to a .npz file instead."
            )
    meta = "# hbjax recording"
    if recording.dt is not None:
        meta += f"; dt = {format_float(recording.dt)}"
    meta += f"; t0 = {format_float(recording.t0)}"
    columns = ([t] if recording.dt is not None else []) + [recording.v, recording.y]
    columns += [recording.channels[n] for n in names]
    header = (["t"] if recording.dt is not None else []) + ["v", "y"] + names
    buf = io.StringIO()
    buf.write(meta + "\n")
    csv.writer(buf, lineterminator="\n").writerow(header)
    for row in zip(*(c.tolist() for c in columns)):
        buf.write(",".join(map(repr, row)) + "\n")
    return atomic_write(path, buf.getvalue(), overwrite=overwrite)
