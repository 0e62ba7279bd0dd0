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

The formatting lives in :mod:`hbjax._core.reprs` and the tables in :mod:`hbjax._core.tables`;
this module re-exports them and adds the model tables and result summaries.

A result class only needs small methods::

    def summary(self):
        return display.report("Title", tables=[...], figures={...}, message=...)

    def __repr__(self):
        return display.pformat(self)

    def _repr_html_(self):
        return self.summary()._repr_html_()
"""

from __future__ import annotations

import html

import jax
import numpy as np

from .._misc import is_traced

from .reprs import (  # noqa: F401 (re-exported: results print through ``display``)
    MAX_ITEMS, Z95, concrete, format_array, format_number, format_result_code, pformat,
    result_message,
)
from .tables import Summary, Table, figure_text, parameter_table, report  # noqa: F401


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
    value = getattr(getattr(result, "result", None), "_value", None)
    if value is not None and (is_traced(value) or np.ndim(value) > 0):
        # batched or traced codes have no single message (a batch's `.message` may even
        # answer with the text of an array of messages): the codes are counted instead
        return figure_text(result.result)
    try:
        return str(result.message)
    except Exception:  # a result kind whose message cannot be read here: its codes
        return figure_text(result.result)


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
    ("criterion_choice", "criterion chosen"),
    ("prediction_whiteness_p", "whiteness p (prediction optimum)"),
    ("gauge", "gauge"),
    ("noise_std", "noise std (criterion's residuals)"),  # equation or output error
    ("sim_fit_pooled", "free-run fit on estimation data (%)"),
    ("sim_fit", "free-run fit per estimation record (%)"),
    ("input_effect_p", "p-value of no input effect"),
    ("whiteness_p", "p-values of residual whiteness, independence"),
    ("stable", "A stable (A3)"),
    ("branches_cross", "branches cross on the data"),
    ("loop_spread", "free-run spread where the loop closes (%)"),
    ("interpolation_ratio", "branch std between recorded inputs / at them"),
    ("free_run_spread", "free-run sd from the covariance (% of output spread)"),
    ("stats.cost", "cost (mean squared residual)"),
    ("stats.initial_cost", "initial cost"),
    ("stats.steps", "optimiser steps"),
    ("stats.samples", "residuals"),
    ("hit_rate", "fraction of starts reaching the best cost"),
    ("best_index", "best start"),
    ("offset", "offset ybar1, eq. (17)"),
    ("gap", "gap P2*(-h_m) - P1*(h_m) (1 expected)"),
    ("b_star_sum_std", "std err of B*(1)"),
    ("static_gain_evidence", "B*(1) != 0 (A5) shown by"),
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
        c = concrete(value)
        empty = isinstance(value, str) and not value
        if value is None or empty or (c is not None and c.dtype.kind == "f" and c.size
                                      and np.all(np.isnan(c))):
            continue  # absent, or not computed (NaN: e.g. residual tests of a good fit)
        if path == "sim_fit" and c is not None and np.any(np.isnan(c)):
            value = ", ".join(record_fit_text(f) for f in np.atleast_1d(c))
        out[label] = value
    if getattr(result, "initial_state", None) is not None:
        out["initial state"] = ("estimated" if result.initial_state == "estimate"
                                else "zero (at rest)")
    costs = concrete(getattr(result, "starts_costs", None))
    if costs is not None:
        out["starts converged"] = f"{int(np.isfinite(costs).sum())} of {costs.shape[-1]}"
    return out


def record_fit_text(fit) -> str:
    """One record's free-run fit as text: ``"97.3 %"``, or why it has none (NaN: a record
    whose output never moves, where the percentage is undefined)."""
    return "undefined (output constant)" if np.isnan(fit) else f"{float(fit):.1f} %"


#: What a success whose branches cross or meet at recorded inputs says of its errors.
KINK_NOTE = ("The branches cross or meet at recorded inputs: the estimate may sit on the "
             "band rule's kink, where these standard errors (a linearisation) can "
             "understate the error (docs/refinement.md, 'The band stays a band').")


def kink_notes(result) -> tuple:
    """:data:`KINK_NOTE` for a concrete, unbatched success with ``branches_cross``."""
    crossed = concrete(getattr(result, "branches_cross", None))
    if crossed is None or crossed.shape != () or not bool(crossed):
        return ()
    return (KINK_NOTE,) if message_of(result) == "success" else ()


def estimation_summary(result, title: str, *, covariance=None, extra=None) -> Summary:
    """:func:`result_summary` with the :func:`result_figures` of `result`, and
    :func:`kink_notes`."""
    return result_summary(result, title, figures=result_figures(result),
                          covariance=covariance, extra=extra, notes=kink_notes(result))


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
