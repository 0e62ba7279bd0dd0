"""Figure of a :class:`hbjax.Recording`: input, output and extra channels against time."""

import matplotlib.pyplot as plt
import numpy as np

from .._io.recording import Recording
from . import checks


def time_axis(n: int, dt=None, t0: float = 0.0) -> tuple[np.ndarray, str]:
    """Sample times and the axis label: seconds when ``dt`` is known, else sample numbers."""
    k = np.arange(n, dtype=np.float64)
    if dt is None:
        return t0 + k, "sample"
    return t0 + k * dt, "time (s)"


def _channel_names(rec, channels) -> list:
    """`channels`: ``True`` (all of the recording's), ``False``/``None`` (none) or a list of
    its channel names."""
    if channels is True:
        return list(rec.channels)
    if channels is False or channels is None:
        return []
    if isinstance(channels, (str, bytes)) or not isinstance(channels, (tuple, list)) \
            or not all(isinstance(n, str) for n in channels):
        raise TypeError("`channels` must be True, False, None or a list of channel names, "
                        f"got {channels!r}.")
    unknown = [n for n in channels if n not in rec.channels]
    if unknown:
        raise ValueError(f"`channels` names {unknown} not in the recording; its channels: "
                         f"{sorted(rec.channels)}.")
    return list(channels)


@checks.closes_on_error
def plot_recording(rec, *, channels=True, axes=None, **line_kwargs):
    """One panel per signal: the input ``v``, the output ``y`` and (with `channels`, or a
    list of channel names) the extra channels, against time in seconds when ``dt`` is
    known. Returns the axes."""
    checks.instance(rec, Recording, "rec", "an hbjax.Recording")
    names = _channel_names(rec, channels)
    signals = [("v (input)", rec.v), ("y (output)", rec.y)]
    signals += [(n, rec.channels[n]) for n in names]
    axes = checks.axes(axes, "axes", count=len(signals))
    if axes is None:
        _, axes = plt.subplots(len(signals), 1, figsize=(8, 1.8 * len(signals) + 0.6),
                               sharex=True, squeeze=False)
        axes = axes[:, 0]
    t, label = time_axis(len(rec), rec.dt, rec.t0)
    # every panel drawn alike (a width popped inside the loop reached the first one only)
    style = line_kwargs if {"lw", "linewidth"} & set(line_kwargs) else {"lw": 1, **line_kwargs}
    for ax, (name, x) in zip(axes, signals):
        ax.plot(t, x, **style)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(label)
    if rec.name:
        axes[0].set_title(rec.name)
    return axes
