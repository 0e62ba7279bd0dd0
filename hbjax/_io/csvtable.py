"""CSV tables of recordings: cells as strings with their line numbers, strict decimal
numbers, the ``# hbjax recording; dt = ...`` comment line of files :func:`hbjax.save_recording`
writes. Errors name the file, row (1-based, as an editor shows it) and column."""

from __future__ import annotations

import csv
import pathlib
import re

import numpy as np

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
            if names.count(key.strip()) > 1:  # which one was meant is not the reader's guess
                where = [j for j, h in enumerate(names) if h == key.strip()]
                raise ValueError(
                    f"{self.path}: the header names {key.strip()!r} for {len(where)} columns "
                    f"({', '.join(map(str, where))}); give the {role} column by its 0-based index."
                )
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
        distinct_columns(self.path, {role: None if j is None else self.column_label(j)
                                     for j, role in zip(idx, roles)})
        return [None if j is None else self.column(j) for j in idx]


def distinct_columns(path, picked: dict) -> None:
    """Refuse one column picked for two roles (``{role: column label or None}``): an output
    read as its own input fits perfectly and means nothing."""
    seen = {}
    for role, label in picked.items():
        if label is None:
            continue
        if label in seen:
            raise ValueError(f"{path}: the {seen[label]} and the {role} are the same column "
                             f"({label}); choose different columns.")
        seen[label] = role


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
