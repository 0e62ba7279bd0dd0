"""Text-and-HTML tables and summaries: :class:`Table`, the parameter table (estimate,
standard error, 95% interval), and :func:`report`, which assembles a :class:`Summary` that
prints as text and renders as HTML in Jupyter. Re-exported by :mod:`hbjax._core.display`.
"""

from __future__ import annotations

import dataclasses
import html

import jax
import numpy as np

from .reprs import (
    Z95, concrete, format_array, format_number, format_result_code, format_value,
    is_result_code, shape_text,
)


@dataclasses.dataclass
class Table:
    """Rows of cells (already strings) under column headers; text and HTML renderings."""

    columns: list[str]
    rows: list[list[str]]
    title: str = ""

    def text(self) -> str:
        cells = [self.columns] + self.rows
        widths = [max(len(r[j]) for r in cells) for j in range(len(self.columns))]

        def line(r):
            first = r[0].ljust(widths[0])
            return "  ".join([first] + [c.rjust(w) for c, w in zip(r[1:], widths[1:])]).rstrip()

        rule = "-" * len(line(self.columns))
        out = ([self.title] if self.title else []) + [line(self.columns), rule]
        return "\n".join(out + [line(r) for r in self.rows])

    def html(self) -> str:
        esc = html.escape
        head = "".join(f"<th>{esc(c)}</th>" for c in self.columns)
        body = "".join("<tr>" + "".join(
            f"<td style='text-align:{'left' if j == 0 else 'right'}'>{esc(c)}</td>"
            for j, c in enumerate(r)) + "</tr>" for r in self.rows)
        cap = f"<caption style='text-align:left'>{esc(self.title)}</caption>" if self.title else ""
        return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def parameter_table(names, estimate, std=None, *, unidentified=None, extra=None,
                    title: str = "", header: str = "estimate") -> Table:
    """Estimate, standard error and 95% interval ``estimate +- 1.96 std`` per parameter,
    with a flag for the parameters named in `unidentified` (which the data do not
    determine: their interval means nothing); a standard error of exactly 0 reads
    "fixed" (a normalisation sets that parameter). `extra` adds columns ``{header: values}``.
    Traced values give a one-row table saying so; a batch (leading axes) gives the mean
    and spread of each parameter over the batch."""
    est, sd = concrete(estimate), None if std is None else concrete(std)
    if est is None or (std is not None and sd is None):
        return Table(["parameter", "estimate"], [["(traced)", shape_text(estimate)]], title)
    flags = set(unidentified or ())
    if est.ndim > 1:
        flat = est.reshape(-1, est.shape[-1])
        rows = [[n, format_number(m), format_number(s)] for n, m, s in
                zip(names, flat.mean(axis=0), flat.std(axis=0))]
        return Table(["parameter", f"mean over {flat.shape[0]}", "spread (std)"], rows, title)
    columns = ["parameter", header]
    if sd is not None:
        columns += ["std err", "95% interval"]
    extra = {k: concrete(v) for k, v in (extra or {}).items()}
    columns += list(extra)
    if flags:
        columns.append("")
    rows = []
    for j, name in enumerate(names):
        row = [name, format_number(est[j])]
        if sd is not None and sd[j] == 0 and np.isfinite(est[j]):
            # exactly 0: a normalisation sets it (b1 = 1 where nb = 1 and B(1) = 1), it is
            # not estimated; a printed "std err 0" would read as a perfect estimate
            row += ["fixed", "(set by the normalisation)"]
        elif sd is not None:
            lo, hi = est[j] - Z95 * sd[j], est[j] + Z95 * sd[j]
            row += [format_number(sd[j]), f"[{format_number(lo)}, {format_number(hi)}]"]
        row += [format_array(v[j]) if v is not None else "?" for v in extra.values()]
        if flags:
            row.append("unidentified" if name in flags else "")
        rows.append(row)
    return Table(columns, rows, title)


class Summary(str):
    """A result's summary: prints as a text table, renders as HTML tables in Jupyter, and is
    an ordinary ``str`` otherwise."""

    def __new__(cls, text: str, html_text: str = ""):
        obj = super().__new__(cls, text)
        obj._html = html_text or f"<pre>{html.escape(text)}</pre>"
        return obj

    def __repr__(self) -> str:
        return str.__str__(self)

    def _repr_html_(self) -> str:
        return self._html


def figure_text(value) -> str:
    if isinstance(value, str):
        return value
    if is_result_code(value):
        return format_result_code(value)
    if isinstance(value, (jax.Array, np.ndarray, np.generic, float, int)):
        return format_array(value)
    return format_value(value, 0, 88)


def report(title: str, *, figures=None, tables=(), message=None, notes=()) -> Summary:
    """A :class:`Summary`: `title`, then ``name: value`` `figures` (fit figures, settings),
    the `tables`, the result `message` and free-text `notes`."""
    figures = {k: figure_text(v) for k, v in (figures or {}).items() if v is not None}
    lines = [title, "=" * len(title)]
    width = max((len(k) for k in figures), default=0)
    lines += [f"{k.ljust(width)} : {v}" for k, v in figures.items()]
    for t in tables:
        lines += ["", t.text()]
    if message is not None:
        lines += ["", f"result: {message}"]
    lines += list(notes)
    esc = html.escape
    parts = [f"<div><strong>{esc(title)}</strong>"]
    if figures:
        parts.append("<table>" + "".join(
            f"<tr><th style='text-align:left'>{esc(k)}</th><td style='text-align:left'>{esc(v)}"
            "</td></tr>" for k, v in figures.items()) + "</table>")
    parts += [t.html() for t in tables]
    if message is not None:
        parts.append(f"<p>result: {esc(str(message))}</p>")
    parts += [f"<p>{esc(n)}</p>" for n in notes]
    return Summary("\n".join(lines), "".join(parts) + "</div>")
