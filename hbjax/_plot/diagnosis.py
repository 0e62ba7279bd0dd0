"""Figure of a mismatch diagnosis (matplotlib)."""

import matplotlib.pyplot as plt
import numpy as np

from .._core.simulate import play, simulate
from .._diagnose.result import Diagnosis, Finding
from . import checks
from .recording import time_axis

_REGIME = {
    "output_saturation": "simulated output",
    "output_nonlinearity": "simulated output",
    "input_saturation": "internal signal u",
    "branch_degree": "input v",
    "coulomb_friction": "motion direction sign(du)",
}


def _regime(effect, v, y_sim, u):
    label = _REGIME.get(effect, "time (samples)")
    if label == "simulated output":
        return y_sim, label
    if label == "internal signal u":
        return u, label
    if label == "input v":
        return v, label
    if effect == "coulomb_friction":
        du = np.diff(u, prepend=u[0])
        return np.sign(du) + 0.15 * np.random.default_rng(0).standard_normal(len(du)), label
    return np.arange(len(v), dtype=float), label


@checks.closes_on_error
def plot_diagnosis(d, *, finding=None, axes=None):
    """Three panels for a :class:`hbjax.Diagnosis`: the nominal simulation residual over
    time with the located windows shaded (held-out part marked); the residual against the
    regime variable that exposed the finding; measured vs simulated output on the held-out
    data before (nominal) and after (extended model).

    **Arguments:** `d` (a Diagnosis), `finding` (default ``d.best``), `axes` (three axes).

    **Returns:** the three axes.
    """
    checks.instance(d, Diagnosis, "d", "an hbjax.Diagnosis")
    if d.v is None or d.y is None or d.nominal is None:
        raise ValueError("`d` holds no recording or nominal model to plot (`v`, `y` or "
                         "`nominal` is None): plot the Diagnosis that hbjax.diagnose returned.")
    if finding is not None:
        checks.instance(finding, Finding, "finding",
                        "None or an hbjax.Finding (one of `d.findings`)")
    axes = checks.axes(axes, "axes", count=3)
    f = d.best if finding is None else finding
    if axes is None:
        _, axes = plt.subplots(3, 1, figsize=(8, 9))
    v, y = np.asarray(d.v), np.asarray(d.y)
    y_nom = np.asarray(simulate(d.nominal, v))
    u = np.asarray(play(d.nominal.backlash, v))
    res = y - y_nom
    dt, t0 = getattr(d, "dt", None), getattr(d, "t0", 0.0)
    t, t_label = time_axis(len(y), dt, t0)
    step = 1.0 if dt is None else dt
    ax = axes[0]
    ax.plot(t, res, lw=0.7, color="C0", label="nominal simulation residual")
    ax.axvspan(t0 + d.n_fit * step, t0 + len(y) * step, color="0.85", zorder=0,
               label="held out")
    if f is not None:
        for i, (a, b) in enumerate(f.where.get("windows", [])):
            ax.axvspan(t0 + a * step, t0 + b * step, color="C3", alpha=0.2,
                       label="located" if i == 0 else None)
    ax.set_xlabel(t_label)
    ax.set_ylabel("y - y_sim")
    ax.set_title(f"diagnosis: {f.effect if f else 'no finding'}")
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[1]
    x, label = _regime(f.effect if f else None, v, y_nom, u)
    if label == "time (samples)":
        x, label = t, t_label
    ax.plot(x, res, ".", ms=2, alpha=0.5)
    ax.set_xlabel(label)
    ax.set_ylabel("y - y_sim")
    ax.grid(alpha=0.3)
    ax = axes[2]
    th = t[d.n_fit:]
    ax.plot(th, y[d.n_fit:], color="k", lw=1, label="measured")
    ax.plot(th, y_nom[d.n_fit:], color="C0", lw=1,
            label=f"nominal ({f.fit_before:.1f}%)" if f else "nominal")
    if f is not None:
        y_new = np.asarray(simulate(f.model, v))
        ax.plot(th, y_new[d.n_fit:], color="C3", lw=1,
                label=f"with {f.effect} ({f.fit_after:.1f}% {f.metric})")
    ax.set_xlabel(f"{t_label} (held out)")
    ax.set_ylabel("y")
    ax.legend(fontsize=8)
    return axes
