"""Readable models and results: numbers in ``repr``, parameter tables as text and HTML.

Every model and result type prints through this module (as statsmodels' summaries do):

- :func:`pformat` writes a module, dataclass, dict or array with its numbers (``repr``),
  falling back to shapes (``f64[3]``) for traced values and to a shape plus range for
  large arrays; a result code prints as its message.
- :class:`Table` is a small table rendering as aligned text and as HTML.
- :func:`parameter_table` builds the estimate / standard error / 95% interval /
  unidentified table from parameter names and values.
- :func:`report` assembles a :class:`Summary` (title, figures, tables, message): a ``str``
  that prints as text and renders as HTML tables in Jupyter.

A result class only needs small methods::

    def summary(self):
        return display.report("Title", tables=[...], figures={...}, message=...)

    def __repr__(self):
        return display.pformat(self)

    def _repr_html_(self):
        return self.summary()._repr_html_()
"""

from __future__ import annotations

import dataclasses
import html
import math

import equinox as eqx
import jax
import numpy as np

Z95 = 1.959963984540054  # two-sided 95% normal quantile
MAX_ITEMS = 12  # arrays with more elements print as shape and range


def concrete(x) -> np.ndarray | None:
    """``x`` as a NumPy array, or ``None`` when it is traced (inside jit/vmap/grad)."""
    if x is None or isinstance(x, jax.core.Tracer):
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


def _shape(x) -> str:
    return eqx.tree_pformat(x)  # "f64[3]", also for tracers


def format_array(x, digits: int = 4) -> str:
    """Numbers of a small concrete array; shape (and range) otherwise."""
    arr = concrete(x)
    if arr is None or arr.dtype == object:
        return _shape(x)
    if arr.ndim == 0:
        return format_number(arr.item(), digits)
    if arr.size <= MAX_ITEMS:
        text = np.array2string(arr, separator=", ", max_line_width=10_000,
                               formatter={"all": lambda v: format_number(v, digits)})
        return text.replace("\n", "")
    if arr.size and np.issubdtype(arr.dtype, np.number):
        return f"{_shape(x)} in [{format_number(np.nanmin(arr))}, {format_number(np.nanmax(arr))}]"
    return _shape(x)


def _is_result_code(x) -> bool:
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


def _format(x, indent: int, width: int) -> str:
    if _is_result_code(x):
        return format_result_code(x)
    if isinstance(x, (jax.Array, np.ndarray, np.generic)):
        return format_array(x)
    if isinstance(x, (bool, int, float)) and not isinstance(x, str):
        return format_number(x) if isinstance(x, float) else repr(x)
    if isinstance(x, dict):
        items = [f"{k!r}: {_format(v, indent + 2, width)}" for k, v in x.items()]
        return _wrap("{", items, "}", indent, width)
    if isinstance(x, (tuple, list)) and not hasattr(x, "_fields"):
        items = [_format(v, indent + 2, width) for v in x]
        open_, close = ("(", ")") if isinstance(x, tuple) else ("[", "]")
        if isinstance(x, tuple) and len(x) == 1:
            close = ",)"
        return _wrap(open_, items, close, indent, width)
    if isinstance(x, eqx.Module):  # structurally, so nested lines indent
        items = [f"{k}={_format(v, indent + 2, width)}" for k, v in _fields(x)]
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
    items = [f"{k}={_format(v, 2, width)}" for k, v in _fields(obj) if k not in skip]
    return _wrap(f"{type(obj).__name__}(", items, ")", 0, width)


# ----------------------------------------------------------------------------- tables


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
    determine: their interval means nothing). `extra` adds columns ``{header: values}``.
    Traced values give a one-row table saying so; a batch (leading axes) gives the mean
    and spread of each parameter over the batch."""
    est, sd = concrete(estimate), None if std is None else concrete(std)
    if est is None or (std is not None and sd is None):
        return Table(["parameter", "estimate"], [["(traced)", _shape(estimate)]], title)
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
        if sd is not None:
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


def _figure_text(value) -> str:
    if isinstance(value, str):
        return value
    if _is_result_code(value):
        return format_result_code(value)
    if isinstance(value, (jax.Array, np.ndarray, np.generic, float, int)):
        return format_array(value)
    return _format(value, 0, 88)


def report(title: str, *, figures=None, tables=(), message=None, notes=()) -> Summary:
    """A :class:`Summary`: `title`, then ``name: value`` `figures` (fit figures, settings),
    the `tables`, the result `message` and free-text `notes`."""
    figures = {k: _figure_text(v) for k, v in (figures or {}).items() if v is not None}
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


# ----------------------------------------------------------------------------- models


def _unbatched(model):
    """The first model of a batch (for names and orders), the model itself otherwise."""
    while np.ndim(model.arx.b) > 1:
        model = jax.tree_util.tree_map(lambda x: x[0], model)
    return model


def model_parameters(model) -> tuple[list[str], object]:
    """Names (:func:`hbjax.param_names`) and values ``(..., p)`` of a Hammerstein model or a
    batch of them (leading axes), in the order a, b, c1, c2."""
    from .params import param_names  # display is imported by the core modules

    names = param_names(_unbatched(model))
    parts = (model.arx.a, model.arx.b, model.backlash.c1, model.backlash.c2)
    arrays = [concrete(x) for x in parts]
    if any(a is None for a in arrays):
        return names, parts[1]  # a traced stand-in: tables fall back to shapes
    return names, np.concatenate(arrays, axis=-1)


def model_table(model, std=None, *, unidentified=None, extra=None, title="",
                header="estimate") -> Table:
    """:func:`parameter_table` of a Hammerstein model's parameters."""
    names, values = model_parameters(model)
    return parameter_table(names, values, std, unidentified=unidentified, extra=extra,
                           title=title, header=header)


def std_from_covariance(covariance):
    """Square roots of the covariance diagonal (``None`` when traced)."""
    cov = concrete(covariance)
    if cov is None:
        return None
    return np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))


def message_of(result) -> str:
    """``result.message``, or the result codes when they are batched or traced."""
    try:
        return str(result.message)
    except Exception:  # batched or traced codes have no single message
        return _figure_text(result.result)


def result_summary(result, title: str, *, figures=None, covariance=None, extra=None,
                   notes=()) -> Summary:
    """The :func:`report` of a result holding a Hammerstein `model`: its parameter table
    (standard errors from `covariance` when given, the names in ``result.unidentified``
    flagged when the result has that field), `figures` and ``result.message``."""
    std = None if covariance is None else std_from_covariance(covariance)
    table = model_table(result.model, std, extra=extra,
                        unidentified=getattr(result, "unidentified", None))
    return report(title, figures=figures, tables=[table], message=message_of(result),
                  notes=notes)


def model_html(model) -> str:
    """HTML of a model: its repr as a heading and, for a Hammerstein model, its table."""
    head = f"<div><code>{html.escape(type(model).__name__)}</code>"
    try:
        table = model_table(model, header="value").html()
    except Exception:  # extensions of the model: their repr only
        table = f"<pre>{html.escape(pformat(model))}</pre>"
    return head + table + "</div>"


# ----------------------------------------------------------------------------- results

#: ``(attribute path, label)`` of the fit figures a result summary shows when present.
FIGURES = (
    ("criterion", "criterion"),
    ("gauge", "gauge"),
    ("noise_std", "noise std (equation error)"),
    ("sim_fit_pooled", "free-run fit on estimation data (%)"),
    ("sim_fit", "free-run fit per estimation record (%)"),
    ("stable", "A stable (A3)"),
    ("branches_cross", "branches cross on the data"),
    ("stats.cost", "cost (mean squared residual)"),
    ("stats.initial_cost", "initial cost"),
    ("stats.steps", "optimiser steps"),
    ("stats.samples", "residuals"),
    ("hit_rate", "starts reaching the best cost"),
    ("best_index", "best start"),
    ("offset", "offset ybar1, eq. (17)"),
    ("gap", "gap P2*(-h_m) - P1*(h_m) (1 expected)"),
    ("b_star_sum_std", "std err of B*(1)"),
    ("cond_ls", "condition number of (26)"),
    ("cond_vandermonde", "condition numbers of (45)-(46)"),
    ("transient", "transient samples skipped"),
    ("rows_ls", "rows of (26)"),
)


def _lookup(obj, path):
    for part in path.split("."):
        if isinstance(obj, dict):
            obj = obj.get(part)
        else:
            obj = getattr(obj, part, None)
        if obj is None:
            return None
    return obj


def result_figures(result) -> dict:
    """The :data:`FIGURES` a result has, labelled."""
    out = {}
    for path, label in FIGURES:
        value = _lookup(result, path)
        if value is not None:
            out[label] = value
    if getattr(result, "initial_state", None) is not None:
        out["initial state"] = ("estimated" if result.initial_state == "estimate"
                                else "zero (at rest)")
    costs = concrete(getattr(result, "starts_costs", None))
    if costs is not None:
        out["starts converged"] = f"{int(np.isfinite(costs).sum())} of {costs.shape[-1]}"
    return out


def estimation_summary(result, title: str, *, covariance=None, extra=None) -> Summary:
    """:func:`result_summary` with the :func:`result_figures` of `result`."""
    return result_summary(result, title, figures=result_figures(result),
                          covariance=covariance, extra=extra)


def findings_table(findings) -> Table:
    """One row per diagnosed effect: held-out fits before/after and the evidence."""
    rows = []
    for i, f in enumerate(findings, 1):
        ev = f.evidence or {}
        ref = "nominal" if ev.get("reference") == "nominal" else "refit"
        rows.append([f"{i}. {f.effect}", f.metric, f"{f.fit_before:.1f}", f"{f.fit_after:.1f}",
                     format_number(ev.get(f"delta_bic_vs_{ref}", float("nan")), 3),
                     format_number(ev.get("dm_z", float("nan")), 3)])
    return Table(["effect", "metric", "fit before %", "fit after %", "dBIC", "DM z"], rows,
                 "findings (held-out fits)")
