"""Plotting (matplotlib). The numerical core never imports this module.

Re-exports the figures of each area: core figures (backlash loops, the paper's signals,
measured vs simulated output), Monte Carlo study plots and diagnosis plots.
"""

from ._plot.core import (
    plot_backlash as plot_backlash,
    plot_output as plot_output,
    plot_staircase as plot_staircase,
)

# --- monte carlo plots (issue 4) ---
from ._plot.monte_carlo import plot_monte_carlo as plot_monte_carlo
# --- diagnosis plots (issue 5) ---
from ._plot.diagnosis import plot_diagnosis as plot_diagnosis
from ._plot.recording import plot_recording as plot_recording
# --- validation plots ---
from ._plot.validation import plot_compare as plot_compare, plot_resid as plot_resid
