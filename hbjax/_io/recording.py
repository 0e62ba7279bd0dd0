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
import os
import pathlib
import tempfile

import numpy as np

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
      Defaults: CSV columns 0 and 1; NPZ arrays ``v`` and ``y`` if present, else the first two
      arrays; BRFD JSON columns ``displacement`` (1) and ``friction force`` (2).
    - `time`: optional column of sample times; ``dt`` is their (uniform) spacing.
    - `dt`: the sampling period, when the file does not give it.

    CSV files may have a header row (detected: a first row with a non-numeric cell) and
    blank or ``#`` comment lines; the delimiter is a comma, semicolon, tab or whitespace.
    Unused columns may hold anything (e.g. blank cells). Errors (``ValueError``) name the
    file, row and column of a missing column, a non-numeric or empty cell, a ragged row, a
    NaN or an empty file.

    **Returns:** a :class:`hbjax.Recording` with ``source`` the path and ``name`` its stem.
    """
    p = pathlib.Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"recording file {str(p)!r} does not exist.")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        columns, file_dt = _read_npz(p, input, output, time)
    elif suffix == ".json":
        columns, file_dt = _read_brfd_json(p, input, output, time)
    else:
        table = read_csv_table(p)
        columns = table.columns([input if input is not None else 0,
                                 output if output is not None else 1,
                                 time], ("input", "output", "time"))
        file_dt = None
    v, y, t = columns
    rec_dt = _resolve_dt(p, t, file_dt, dt)
    return Recording(v=v, y=y, dt=rec_dt, source=str(p), name=p.stem)


def _resolve_dt(p, t, file_dt, dt):
    if dt is not None:
        return dt
    if t is not None:
        return _uniform_step(t, p)
    return file_dt


def _uniform_step(t: np.ndarray, p) -> float:
    if t.shape[0] < 2:
        raise ValueError(f"{p}: the time column needs at least 2 samples to give `dt`.")
    steps = np.diff(t)
    step = float(np.median(steps))
    if not step > 0:
        raise ValueError(f"{p}: the time column must increase, got median step {step!r}.")
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

    def __init__(self, path, header, rows, lines):
        self.path, self.header, self.rows, self.lines = path, header, rows, lines

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
                out[r] = float(cell)
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
    numbered = [
        (i + 1, line)
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]
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
    return CsvTable(p, header, [c for _, c in rows], [n for n, _ in rows])


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
            arr = archive[key]
            if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.number):
                raise ValueError(
                    f"{p}: array {key!r} must be a 1-D numeric array, got shape {arr.shape} "
                    f"dtype {arr.dtype}."
                )
            arr = arr.astype(np.float64)
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise ValueError(f"{p}: array {key!r} has NaN or inf at index {bad[0]}.")
            return arr

        cols = [get(input, "input"), get(output, "output"), get(time, "time")]
        file_dt = None
        if "dt" in names:
            file_dt = float(np.asarray(archive["dt"]).reshape(()))
    if cols[0].shape != cols[1].shape:
        raise ValueError(
            f"{p}: input and output arrays differ in length ({cols[0].shape[0]} and "
            f"{cols[1].shape[0]})."
        )
    return cols, file_dt


def _read_brfd_json(p, input, output, time):
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not valid JSON ({exc}).") from None
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
                raise ValueError(f"{p}: non-numeric value {cell!r} at data row {r}, column {j}.")
            col[r] = cell
            if not np.isfinite(col[r]):
                raise ValueError(f"{p}: NaN or inf at data row {r}, column {j}.")
        cols.append(col)
    file_dt = doc.get("dt")
    if file_dt is not None and (isinstance(file_dt, bool) or not isinstance(file_dt, (int, float))):
        raise ValueError(f"{p}: `dt` must be a number, got {file_dt!r}.")
    return cols, file_dt


# ----------------------------------------------------------------------------- writing


def atomic_write(path, data: str | bytes, *, overwrite: bool = False) -> pathlib.Path:
    """Write ``data`` to ``path`` all at once: a temporary file in the same directory is
    filled, flushed to disk and renamed over ``path``, so an interrupted run never leaves a
    truncated file. An existing ``path`` is kept unless ``overwrite`` is true."""
    p = pathlib.Path(path)
    if p.exists() and not overwrite:
        raise FileExistsError(
            f"{str(p)!r} already exists; pass overwrite=True (--force on the command line) "
            "to replace it."
        )
    if p.is_dir():
        raise IsADirectoryError(f"{str(p)!r} is a directory, not a file.")
    parent = p.parent if str(p.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"folder {str(parent)!r} of {str(p)!r} does not exist.")
    payload = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
    try:
        # mkstemp makes the file private (0600); give it the mode an ordinary open() would.
        os.chmod(tmp, _default_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, p)
        else:
            # link() fails if the target appeared meanwhile: no clobbering even in a race.
            try:
                os.link(tmp, p)
            except FileExistsError:
                raise FileExistsError(
                    f"{str(p)!r} already exists; pass overwrite=True (--force) to replace it."
                ) from None
            except OSError:  # file systems without hard links
                os.replace(tmp, p)
            else:
                os.unlink(tmp)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return p


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def format_float(x: float) -> str:
    """Shortest decimal that reads back to the same float64 (``repr``)."""
    return repr(float(x))


def save_recording(path, recording: Recording, *, overwrite: bool = False) -> pathlib.Path:
    """Write ``recording`` as CSV with header ``v,y`` (``t,v,y`` when ``dt`` is known).

    Values are written with the shortest exact decimal, so :func:`load_recording` reads back
    the same float64 numbers (and the same ``dt`` through ``time="t"``). Atomic, and an
    existing file is kept unless ``overwrite``.
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"`recording` must be an hbjax.Recording, got {type(recording).__name__}.")
    buf = io.StringIO()
    if recording.dt is None:
        buf.write("v,y\n")
        for v, y in zip(recording.v, recording.y):
            buf.write(f"{format_float(v)},{format_float(y)}\n")
    else:
        buf.write("t,v,y\n")
        for t, v, y in zip(recording.t, recording.v, recording.y):
            buf.write(f"{format_float(t)},{format_float(v)},{format_float(y)}\n")
    return atomic_write(path, buf.getvalue(), overwrite=overwrite)
