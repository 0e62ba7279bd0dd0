"""Validation figures: measured vs model outputs (``compare``) and residual correlations
with their 99% bands (``resid``)."""

import matplotlib.pyplot as plt
import numpy as np

from .._core.model import AbstractModel
from .._identify.compare import Comparison, compare
from .._identify.refine_result import AbstractRefinement
from .._identify.residual_analysis import ResidualAnalysis, resid
from . import checks
from .recording import time_axis


@checks.closes_on_error
def plot_compare(result, v=None, y=None, *, ax=None, window=None, **compare_kwargs):
    """Measured output and each model's output, fit (%) in the legend, as MATLAB's
    ``compare`` figure.

    **Arguments:**

    - `result`: a :class:`hbjax.Comparison`, or a model or a result of refine / fit (or a
      list of them) to compare on `v`, `y` (or an :class:`hbjax.Recording` as `v`) with
      ``compare_kwargs`` (``initial_state``, ``horizon``, ``names``). A Comparison is
      drawn as computed: `v`, `y` and ``compare_kwargs`` are then refused, not ignored.
    - `ax`: matplotlib axes (a new figure if ``None``).
    - `window`: ``(start, stop)`` samples to show, ``0 <= start < stop <= len(y)``.

    The time axis is in seconds when the recording's ``dt`` is known. A result of
    :func:`hbjax.refine` or :func:`hbjax.fit` compared freely gets a band of two standard
    deviations of its free run, from the estimate's own covariance (``Comparison.y_std``;
    none where an unidentified parameter makes it infinite).

    **Returns:** the axes.
    """
    ax = checks.axes(ax, "ax")
    if isinstance(result, Comparison):
        # a computed comparison is drawn as it is: arguments to compute another are refused
        # rather than ignored
        given = [f"`{n}`" for n, x in (("v", v), ("y", y)) if x is not None]
        given += [f"`{n}`" for n in compare_kwargs]
        if given:
            raise TypeError(f"{', '.join(given)}: `result` is a Comparison, drawn as computed; "
                            f"pass the model instead to compare it on other data or settings.")
    else:
        if not isinstance(result, (AbstractModel, AbstractRefinement, list, tuple)):
            raise TypeError(f"`result` must be a Comparison, an hbjax model, a result of "
                            f"refine / fit, or a list of them, got {type(result).__name__}.")
        if v is None:
            raise TypeError("`v` is missing: pass a Comparison, or a model with `v` and `y`.")
        result = compare(result, v, y, **compare_kwargs)
    sl = slice(*checks.window(window, result.y.shape[0]))
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3.5))
    t, label = time_axis(result.y.shape[0], result.dt)
    ax.plot(t[sl], result.y[sl], color="k", lw=1.2, label="measured")
    for k, (name, fit) in enumerate(zip(result.names, result.fits)):
        ax.plot(t[sl], result.y_hats[k][sl], lw=1, color=f"C{k}", label=f"{name}: {fit:.1f}%")
        sd = result.y_stds[k][sl]
        if np.all(np.isfinite(sd)):
            ax.fill_between(t[sl], result.y_hats[k][sl] - 2 * sd, result.y_hats[k][sl] + 2 * sd,
                            color=f"C{k}", alpha=0.2, lw=0, label=f"{name}: +-2 sd of the estimate")
    mode = "simulated" if result.horizon is None else f"{result.horizon}-step prediction"
    ax.set_title(f"measured vs {mode} output (initial state: {result.initial_state})")
    ax.set_xlabel(label)
    ax.set_ylabel("y")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return ax


@checks.closes_on_error
def plot_resid(result, v=None, y=None, *, axes=None, lags=None):
    """Residual autocorrelation and cross-correlation with past inputs, each with the 99%
    band, as MATLAB's ``resid`` figure.

    **Arguments:** `result` (a :class:`hbjax.ResidualAnalysis`, drawn as computed; or a
    model analysed on `v`, `y` with `lags`, default 25), `axes` (two matplotlib axes or
    ``None``).

    **Returns:** the two axes.
    """
    axes = checks.axes(axes, "axes", count=2)
    if isinstance(result, ResidualAnalysis):
        given = [f"`{n}`" for n, x in (("v", v), ("y", y), ("lags", lags)) if x is not None]
        if given:
            raise TypeError(f"{', '.join(given)}: `result` is a ResidualAnalysis, drawn as "
                            f"computed; pass the model instead to analyse other data or lags.")
    else:
        if isinstance(getattr(result, "model", None), AbstractModel):  # a fit / refine result
            result = result.model
        if not isinstance(result, AbstractModel):
            raise TypeError("`result` must be an hbjax.ResidualAnalysis (from hbjax.resid) or "
                            f"a model analysed on `v` and `y`, got {type(result).__name__}.")
        if v is None:
            raise TypeError("`v` is missing: pass a ResidualAnalysis, or a model with `v` and `y`.")
        result = resid(result, v, y) if lags is None else resid(result, v, y, lags=lags)
    if axes is None:
        _, axes = plt.subplots(2, 1, figsize=(7, 5))
    k_auto = np.arange(1, result.lags + 1)
    k_cross = np.arange(0, result.lags + 1)
    panels = (
        (axes[0], k_auto, result.autocorrelation,
         f"residual autocorrelation (Ljung-Box p = {result.p_whiteness:.3g})"),
        (axes[1], k_cross, result.cross_correlation,
         f"cross-correlation with past inputs v(t-k) (p = {result.p_independence:.3g})"),
    )
    for ax, lag, r, title in panels:
        outside = np.abs(r) > result.band
        ax.vlines(lag, 0, r, color="C0")
        ax.plot(lag[outside], r[outside], "o", color="C3", ms=4)
        ax.plot(lag[~outside], r[~outside], "o", color="C0", ms=3)
        ax.axhspan(-result.band, result.band, color="C1", alpha=0.2, label="99% band")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("lag k (samples)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    return axes
