"""Helpers the effects' physics sentences share: rounding for text, where an extension
changes the simulated output (time windows) and clip masks. Each effect's sentence itself
is its class's ``describe``."""

from __future__ import annotations

import numpy as np

from .residual_tests import windows


def rounded(x, digits=4):
    """``x`` to ``digits`` significant digits (for sentences and reports)."""
    return float(f"{float(x):.{digits}g}")


def effect_windows(info, mask=None):
    """Where the extension changes the simulated output materially (or ``mask``)."""
    y, ys, yr = info["y"], info["ysim"], info["ysim_ref"]
    if mask is None:
        diff = np.abs(ys - yr)
        scale = float(np.sqrt(np.mean((y - ys) ** 2))) or 1.0
        mask = diff > 0.5 * scale
    return windows(mask, min_gap=max(5, len(y) // 200))


def saturation_mask(signal, lo, hi):
    """Samples of ``signal`` at a clip level (``None``: that side is open), to a
    tolerance relative to the levels and the signal's spread, so that the mask does not
    depend on the signal's unit (an absolute floor took every sample of a record in
    nanovolts for clipped)."""
    n = len(signal)
    signal = np.asarray(signal)
    tol = 1e-9 * max(abs(lo or 0.0), abs(hi or 0.0), float(np.ptp(signal)) if n else 0.0)
    low = signal <= lo + tol if lo is not None else np.zeros(n, bool)
    high = signal >= hi - tol if hi is not None else np.zeros(n, bool)
    return low | high
