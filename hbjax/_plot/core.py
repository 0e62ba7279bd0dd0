"""Figures of the core: backlash loops, the paper's v3/u* (Figs. 3-4), outputs."""

import matplotlib.pyplot as plt
import numpy as np

from .._core.signals import GiriDesign
from .._core.simulate import play
from .._misc import check_bool, positive_float, positive_int, same_length
from . import checks
from .recording import time_axis


def _axes(ax):
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4))
    return ax


@checks.closes_on_error
def plot_backlash(backlash, v_range, *, ax=None, label=None, color=None, sweep=True):
    """Draw the branches ``P1`` (rising) and ``P2`` (falling) of the :class:`hbjax.Backlash`
    `backlash` over ``v_range = (lo, hi)`` (finite, ``lo < hi``) and, with ``sweep``, the loop
    the play operator traces under a full triangular sweep. Returns the axes."""
    sweep = check_bool(sweep, "sweep")
    backlash = checks.backlash(backlash)
    lo, hi = checks.interval(v_range, "v_range")
    ax = _axes(checks.axes(ax, "ax"))
    v = np.linspace(lo, hi, 400)
    line = ax.plot(v, np.asarray(backlash.p1(v)), color=color, lw=1, ls="--",
                   label=None if label is None else f"{label}: P1, P2")[0]
    ax.plot(v, np.asarray(backlash.p2(v)), color=line.get_color(), lw=1, ls="--")
    if sweep:
        v_loop = np.concatenate([np.linspace(0, hi, 200), np.linspace(hi, lo, 400),
                                 np.linspace(lo, hi, 400)])
        u = np.asarray(play(backlash, v_loop))
        ax.plot(v_loop[200:], u[200:], color=line.get_color(), lw=2,
                label=None if label is None else f"{label}: loop")
    ax.set_xlabel("v")
    ax.set_ylabel("u")
    ax.grid(alpha=0.3)
    if label is not None:
        ax.legend(fontsize=8)
    return ax


@checks.closes_on_error
def plot_staircase(design, backlash, *, periods=2, axes=None):
    """The paper's Figs. 3-4: ``v3`` of the :class:`hbjax.GiriDesign` `design` over
    `periods` (an integer >= 1) periods and the internal signal ``u*`` of the
    :class:`hbjax.Backlash` `backlash`, in two `axes`. Returns the axes."""
    checks.instance(design, GiriDesign, "design", "an hbjax.GiriDesign")
    backlash = checks.backlash(backlash)
    periods = positive_int(periods, "periods")
    axes = checks.axes(axes, "axes", count=2)
    if axes is None:
        _, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    T = periods * design.staircase_period
    v3 = design.staircase_input(T)
    u = np.asarray(play(backlash, v3))
    t = np.arange(T)
    axes[0].step(t, v3, where="post")
    axes[0].set_ylabel("v3(t)")
    axes[0].set_title(f"v3, eq. (32): n={design.n}, m={design.m}, h_m={design.h_m:g}")
    axes[1].step(t, u, where="post", color="C1")
    axes[1].set_ylabel("u*(t)")
    axes[1].set_xlabel("t")
    for ax in axes:
        ax.grid(alpha=0.3)
    return axes


@checks.closes_on_error
def plot_output(y_measured, y_simulated, *, ax=None, labels=("measured", "simulated"), window=None,
                dt=None):
    """Measured vs simulated output (1-D records of equal length; optionally only the samples
    ``window = (start, stop)``, ``0 <= start < stop <= len``), against time in seconds when
    the sampling period `dt` (> 0) is given, else sample numbers. Returns the axes."""
    y_measured = checks.output(y_measured, "y_measured")
    y_simulated = checks.output(y_simulated, "y_simulated")
    same_length(y_measured=y_measured, y_simulated=y_simulated)
    start, stop = checks.window(window, len(y_measured))
    dt = None if dt is None else positive_float(dt, "dt")
    if isinstance(labels, (str, bytes)) or not isinstance(labels, (tuple, list)) \
            or len(labels) != 2:
        raise TypeError(f"`labels` must be a pair (measured, simulated) of labels, got {labels!r}.")
    ax = _axes(checks.axes(ax, "ax"))
    t, label = time_axis(len(y_measured), dt)
    ax.plot(t[start:stop], y_measured[start:stop], lw=1, label=labels[0])
    ax.plot(t[start:stop], y_simulated[start:stop], lw=1, ls="--", label=labels[1])
    ax.set_xlabel(label)
    ax.set_ylabel("y")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax
