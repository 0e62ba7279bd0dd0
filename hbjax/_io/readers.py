"""Readers of the NPZ archive and BRFD-layout JSON recordings (NumPy only, no JAX), with
errors that name the file, array or column."""

from __future__ import annotations

import json

import numpy as np

from .csvtable import distinct_columns

# Column names of the BRFD JSON layout (banded rotary friction device, see hbjax/data/README.md).
BRFD_COLUMNS = (
    "time",
    "displacement",
    "friction force",
    "velocity",
    "actuator force 1",
    "actuator force 2",
)



def read_npz(p, input, output, time):
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

        def resolve(key, role):
            """The array name that `key` (a name or an index) selects for `role`."""
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
            return key

        def load(key):
            if key is None:
                return None
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

        keys = {role: resolve(key, role)
                for role, key in (("input", input), ("output", output), ("time", time))}
        distinct_columns(p, {role: None if key is None else f"array {key!r}"
                             for role, key in keys.items()})
        cols = [load(keys["input"]), load(keys["output"]), load(keys["time"])]
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


def read_brfd_json(p, input, output, time):
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
    distinct_columns(p, {role: None if j is None else f"column {BRFD_COLUMNS[j]!r}"
                         for j, role in zip(idx, ("input", "output", "time"))})
    cols = [None if j is None else _brfd_column(rows, j, p) for j in idx]
    # The other named columns (velocity, actuator forces) are the record's channels, as
    # hbjax.datasets.brfd gives them; one that does not hold numbers is left out.
    channels = {}
    for j in range(1, min(width, len(BRFD_COLUMNS))):
        if j not in idx:
            try:
                channels[BRFD_COLUMNS[j]] = _brfd_column(rows, j, p)
            except ValueError:
                pass
    file_dt = doc.get("dt")
    if file_dt is not None and (isinstance(file_dt, bool) or not isinstance(file_dt, (int, float))):
        raise ValueError(f"{p}: `dt` must be a number, got {_short(file_dt)}.")
    if file_dt is not None:
        try:
            file_dt = float(file_dt)
        except OverflowError:
            raise ValueError(f"{p}: `dt` is too large for a float64.") from None
    return cols, file_dt, channels


def _brfd_column(rows, j: int, p) -> np.ndarray:
    """Column ``j`` of a BRFD file's rows as float64, every cell checked."""
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
    return col


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
