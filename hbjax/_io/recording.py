"""Recordings in and out: the :class:`Recording` record, :func:`load_recording` (over the
CSV table of :mod:`.csvtable` and the NPZ/JSON readers of :mod:`.readers`) and the CSV
writer, through the atomic no-clobber file writer of :mod:`.files`.

Readers parse in plain Python/NumPy (no JAX) and report bad input by file, row and column, so
a researcher can open the file at the offending cell: rows are counted 1-based as a text editor
shows them (the header is row 1), columns by their header name when there is one.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import pathlib

import numpy as np

from .._misc import check_bool
from .files import as_path, atomic_write as atomic_write, check_readable

from . import frames as _frames
from .csvtable import read_csv_table
from .readers import BRFD_COLUMNS as BRFD_COLUMNS, read_brfd_json, read_npz


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

    The arrays are finite and hold at least one sample, and ``t0`` is a finite number;
    anything else is refused at construction.
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
        v = _frames.finite_column(self.v, "`v`")
        y = _frames.finite_column(self.y, "`y`")
        if v.shape != y.shape:
            raise ValueError(
                f"`v` and `y` must have equal lengths, got {v.shape[0]} and {y.shape[0]} samples."
            )
        object.__setattr__(self, "v", v)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "dt", _frames.sampling_period(self.dt))
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "channels", _frames.check_channels(self.channels, v.shape[0]))
        object.__setattr__(self, "t0", _frames.time_origin(self.t0))
        _frames.check_times(self)

    def __len__(self) -> int:
        return int(self.v.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Sample times ``t0 + k * dt`` (seconds), or sample indices ``t0 + k`` when ``dt``
        is ``None``."""
        k = np.arange(len(self), dtype=np.float64)
        return self.t0 + (k if self.dt is None else k * self.dt)

    def slice(self, start: int | None = None, stop: int | None = None) -> "Recording":
        """The samples ``start:stop`` (Python's slice rules) as a new record (same ``dt``,
        ``source`` and ``name``; channels sliced alike, times kept). A slice that keeps no
        sample is refused."""
        for name, bound in (("start", start), ("stop", stop)):
            if bound is not None and (isinstance(bound, bool)
                                      or not isinstance(bound, (int, np.integer))):
                raise TypeError(f"`{name}` must be an integer sample index or None, got "
                                f"{bound!r}.")
        index = slice(start, stop)
        if len(range(*index.indices(len(self)))) == 0:
            raise ValueError(f"`start`={start!r}, `stop`={stop!r} keep no sample of a "
                             f"{len(self)}-sample recording.")
        return _frames.take(self, index)

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
    - The file's other columns become the recording's `channels` (offered to
      :func:`hbjax.diagnose`): those :func:`save_recording` wrote; in any other CSV file,
      every other column that holds a finite number in every row, named by its header
      (``column j`` without one), except one headed ``t`` or ``time``; a BRFD file's
      velocity and actuator forces.
    - `time`: optional column of sample times; ``dt`` is their (uniform) spacing. Times
      written as ``k * dt`` give back ``dt`` exactly.
    - `dt`: the sampling period, when the file does not give it. A `dt` that disagrees by
      more than 0.1 % with the file's (the mean step of `time`, or the file's own ``dt``)
      is refused with a ``ValueError`` naming both, rather than silently preferred.

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
    dt = _frames.sampling_period(dt)  # an argument error, before the file is read
    p = check_readable(path, "recording file")
    suffix = p.suffix.lower()
    t0, channels = 0.0, {}
    if suffix == ".npz":
        columns, file_dt, t0, channels = read_npz(p, input, output, time)
    elif suffix == ".json":
        columns, file_dt, channels = read_brfd_json(p, input, output, time)
    else:
        table = read_csv_table(p)
        v_col, y_col = table.default_columns()
        keys = [input if input is not None else v_col, output if output is not None else y_col,
                time]
        columns = table.columns(keys, ("input", "output", "time"))
        file_dt = table.dt
        used = {table.index(k, "column") for k in keys if k is not None}
        used |= {j for j in [table.named("t")] if j is not None}
        extra = [j for j in range(table.n_columns) if j not in used]
        if table.meta is not None:  # written by save_recording: its t0 and channels too
            t0 = table.meta.get("t0", 0.0)
            seen = {}
            for j in extra:
                name = table.header[j].strip()
                if name in seen:  # a dict would keep the last and drop the first unseen
                    raise ValueError(
                        f"{p}: the channel {name!r} is named by two header columns "
                        f"({seen[name]} and {j}, 0-based); rename one of them.")
                seen[name] = j
            channels = {table.header[j].strip(): table.column(j) for j in extra}
        else:
            # (a column named as a time axis is not a recorded signal)
            channels = _numeric_channels(table, [
                j for j in extra if table.header is None
                or table.header[j].strip().lower() not in ("t", "time")])
    v, y, t = columns
    rec_dt = _resolve_dt(p, t, file_dt, dt, time)
    if t is not None:
        t0 = float(t[0])
    try:
        return Recording(v=v, y=y, dt=rec_dt, source=str(p), name=p.stem, channels=channels,
                         t0=t0)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{p}: {exc}") from None


def _numeric_channels(table, extra) -> dict:
    """The unused columns of a CSV file not written by :func:`save_recording` that hold a
    finite number in every row, as channels named by the header (``column j`` where it
    has no header or no name; a repeated name gets its column's index). Other unused
    columns (notes, blank cells) are left out, as before."""
    channels = {}
    for j in extra:
        try:
            values = table.column(j)
        except ValueError:
            continue
        name = table.header[j].strip() if table.header is not None else ""
        if not name or name in channels:
            name = f"{name} (column {j})".strip() if name else f"column {j}"
        channels[name] = values
    return channels


def _resolve_dt(p, t, file_dt, dt, time):
    """The file's sampling period (its time column, else its own ``dt`` entry), or the
    given `dt` when the file has none; a given `dt` the file contradicts is refused."""
    if dt is None:
        if t is not None:
            # The file's own dt when its times are exactly t0 + k * dt (save_recording's
            # layout).
            if file_dt is not None and np.array_equal(
                    t[0] + np.arange(t.shape[0]) * file_dt, t):
                return file_dt
            return _uniform_step(t, p)
        return file_dt
    try:
        if t is not None and t.shape[0] >= 2:
            return _frames.check_dt_agrees(
                dt, (float(t[-1]) - float(t[0])) / (t.shape[0] - 1),
                f"the step of the time column {time!r}",
                "give only one of them: leave out `dt` to use the times, or `time` to use `dt`")
        if file_dt is not None:
            return _frames.check_dt_agrees(
                dt, file_dt, "the file's own dt",
                "leave out `dt` to use the file's, or replace it after loading "
                "(dataclasses.replace(rec, dt=...))")
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None
    return dt


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
    overwrite = check_bool(overwrite, "overwrite")
    if not isinstance(recording, Recording):
        raise TypeError(f"`recording` must be an hbjax.Recording, got {type(recording).__name__}.")
    suffix = as_path(path).suffix.lower()
    if suffix == ".json":
        raise ValueError(
            f"{str(path)!r}: save_recording writes CSV or .npz; a .json file would be read back "
            "as the BRFD layout. Choose a .csv or .npz name."
        )
    _frames.check_times(recording)
    t = recording.t
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
