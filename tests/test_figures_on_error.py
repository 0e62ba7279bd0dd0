"""A figure call that fails on a matplotlib argument it passes through leaves no figure
open: the figure it created is closed, one the caller gave is kept."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import hbjax  # noqa: E402
import hbjax.plot  # noqa: E402

BACKLASH = hbjax.Backlash(c1=[0.5, 1.0], c2=[-0.5, 1.0])
REC = hbjax.Recording(np.arange(50.0), np.sin(np.arange(50.0)), channels={"w": np.ones(50)})

FAILING = {
    "plot_backlash": lambda **kw: hbjax.plot.plot_backlash(BACKLASH, (-2, 2), color="nocolour",
                                                           **kw),
    "plot_recording": lambda **kw: hbjax.plot.plot_recording(REC, color="nocolour", **kw),
}


@pytest.mark.parametrize("name", sorted(FAILING))
def test_a_failed_figure_is_closed(name):
    plt.close("all")
    with pytest.raises(ValueError, match="nocolour"):
        FAILING[name]()
    assert plt.get_fignums() == []


def test_a_callers_figure_stays_open_after_a_failure():
    plt.close("all")
    fig, ax = plt.subplots()
    with pytest.raises(ValueError, match="nocolour"):
        FAILING["plot_backlash"](ax=ax)
    assert plt.get_fignums() == [fig.number]
    plt.close("all")


def test_a_successful_figure_stays_open():
    plt.close("all")
    ax = hbjax.plot.plot_backlash(BACKLASH, (-2, 2))
    assert plt.get_fignums() == [ax.figure.number]
    plt.close("all")
