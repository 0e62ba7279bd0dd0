"""Figures of a Monte Carlo :class:`hbjax.Study`: RMSE vs record length on log-log axes with
the ``N^-1/2`` reference, and per-parameter histograms of the estimation errors."""

import matplotlib.pyplot as plt
import numpy as np

from .._misc import is_real_scalar, positive_int
from .._montecarlo.study import Study
from . import checks


def _selection(params, names) -> list[int]:
    """Indices of the parameter names `params` (``None``: all)."""
    if params is None:
        return list(range(len(names)))
    if isinstance(params, (str, bytes)) or not isinstance(params, (tuple, list)) or not params \
            or not all(isinstance(p, str) for p in params):
        raise TypeError(f"`params` must be None or a non-empty list of parameter names, "
                        f"got {params!r}.")
    unknown = [p for p in params if p not in names]
    if unknown:
        raise ValueError(f"`params` names {unknown}, not parameters of the study; its "
                         f"parameters: {names}.")
    return [names.index(p) for p in params]


@checks.closes_on_error
def plot_monte_carlo(study, *, params=None, length_index=-1, bins=30, fig=None):
    """Plot a Monte Carlo study.

    Left: RMSE of every (selected) normalised parameter vs record length ``N`` on log-log
    axes, with the ``N^-1/2`` reference line through the first point of each parameter
    (a consistent estimator at the ``sqrt(N)`` rate runs parallel to it). Right: one
    histogram per parameter of the errors ``theta_hat - theta*`` at ``lengths[length_index]``
    (needs ``keep_estimates=True``; without it only the RMSE panel is drawn).

    **Arguments:** `study` (a :class:`hbjax.Study`), `params` (a list of parameter names to
    show, default all), `length_index` (which length the histograms show, an index into
    ``study.lengths``), `bins` (a number of bins >= 1, or any ``bins`` matplotlib's ``hist``
    takes), `fig` (a figure to draw in).

    **Returns:** the matplotlib ``Figure``.
    """
    checks.instance(study, Study, "study", "an hbjax.Study")
    names = list(study.names)
    sel = _selection(params, names)
    n_len = len(study.lengths)
    if not isinstance(length_index, (int, np.integer)) or isinstance(length_index, bool):
        raise TypeError(f"`length_index` must be an integer, got {length_index!r}.")
    if not -n_len <= length_index < n_len:
        raise ValueError(f"`length_index` must index one of the study's {n_len} lengths "
                         f"({-n_len} to {n_len - 1}), got {length_index}.")
    if is_real_scalar(bins):
        positive_int(bins, "bins")
    fig = checks.figure(fig)
    hist = study.estimates is not None
    ncols = int(np.ceil(np.sqrt(len(sel)))) if hist else 0
    nrows = int(np.ceil(len(sel) / ncols)) if hist else 1
    if fig is None:
        fig = plt.figure(figsize=(5 + 2.3 * ncols, max(4.0, 2.0 * nrows)), layout="constrained")
    grid = fig.add_gridspec(nrows, 1 + ncols, width_ratios=[2.2] + [1] * ncols)
    ax = fig.add_subplot(grid[:, 0])
    lengths = np.asarray(study.lengths, float)
    order = np.argsort(lengths)
    for k, p in enumerate(sel):
        color = f"C{k % 10}"
        rmse = study.rmse[order, p]
        ax.loglog(lengths[order], rmse, "o-", color=color, label=f"{names[p]} ({study.slope[p]:+.2f})")
        ok = np.isfinite(rmse) & (rmse > 0)
        if ok.any():
            i0 = np.flatnonzero(ok)[0]
            ref = rmse[i0] * np.sqrt(lengths[order][i0] / lengths[order])
            ax.loglog(lengths[order], ref, ":", color=color, lw=1)
    ax.plot([], [], "k:", lw=1, label=r"$N^{-1/2}$ reference")
    ax.set_xlabel("record length N per experiment")
    ax.set_ylabel("RMSE of normalised estimate")
    ax.set_title(f"{study.estimator}, {study.noise} noise: RMSE vs N (slope)")
    ax.legend(fontsize="small", ncol=1 if len(sel) <= 6 else 2)
    ax.grid(True, which="both", alpha=0.3)
    if hist:
        li = length_index % len(study.lengths)
        valid = study.codes[li] == 0
        for k, p in enumerate(sel):
            axh = fig.add_subplot(grid[k // ncols, 1 + k % ncols])
            err = study.estimates[li, valid, p] - study.true[p]
            axh.hist(err, bins=bins, color=f"C{k % 10}", alpha=0.8)
            axh.axvline(0.0, color="k", lw=1)
            axh.axvline(study.bias[li, p], color="r", lw=1, ls="--")
            axh.set_title(f"{names[p]}, N={study.lengths[li]}", fontsize="small")
            axh.tick_params(labelsize="x-small")
    return fig
