"""Where the diagnosis splits a record into its fitting and held-out parts.

Every candidate is fitted on the first part and judged on the second (held-out free-run
simulation), so the held-out part must exercise the system as much as the fitting part:
a record that ends at rest (a test rig ramping down, a plant left idle) would otherwise
put a quiet tail in the held-out part, where every model fits about equally well (no
decision) or, with a tiny output spread, the fit percentages explode (a held-out fit of
-965% from a few millivolts of error on a flat tail).

The split stays a single cut (the simulation of the held-out part continues from the
state the fitting part ends in, as a user's validation would). Its position is chosen by
**excitation**: the spread of the input, of the output and of the input's rate (standard
deviations) in the held-out part, each relative to the same quantity in the fitting part.
The smallest of the three ratios is the split's excitation ratio. The output
:func:`hbjax.diagnose` passes is the nominal model's free run, the output the input drives
as the model sees it: the measured output carries the very mismatch under diagnosis (a
plant whose gain drops after a parameter change shows a quieter measured tail, and moving
the cut for it put the change into the held-out part, where no fit can see it). The
requested fraction is kept when its ratio is at least :data:`MIN_RATIO`; otherwise the cut
moves earlier (held-out fractions up to :data:`MAX_FRACTION`, in steps of 2.5% of the
record) to the first position whose ratio reaches :data:`MIN_RATIO`, or to the largest
ratio when none does, so that the held-out part also holds excited data and a quiet tail
cannot decide.

A move must not take the mismatch out of the fitting part. The nominal model's free-run
error (measured output minus that free run) shows where the mismatch is; a cut is skipped
when the held-out part's mean squared error would exceed the fitting part's more than
:data:`MAX_ERROR_RATIO` times and more than at the requested cut. A plant whose gain
changes late in a record with a quieter tail is the case: moving the cut for excitation
put the change into the held-out part (error ratio 7.3 at the requested cut, 12.9 at the
moved one), where no fit can see it.
"""

from __future__ import annotations

import numpy as np

#: held-out part kept as requested when its excitation is at least this fraction of the
#: fitting part's (input spread, output spread and input rate each)
MIN_RATIO = 0.7
#: largest held-out fraction the cut may move to
MAX_FRACTION = 0.5
#: a moved cut may not leave the held-out part with more than this many times the fitting
#: part's mean squared nominal free-run error (unless the requested cut already does);
#: records without a mismatch gave ratios of 0.68-1.56 at their cuts
MAX_ERROR_RATIO = 4.0
_STEP = 0.025


def excitation(v: np.ndarray, y: np.ndarray) -> dict:
    """Spread of one segment: ``{"input", "output", "input_rate"}`` standard deviations."""
    return {"input": float(np.std(v)), "output": float(np.std(y)),
            "input_rate": float(np.std(np.diff(v))) if len(v) > 1 else 0.0}


def excitation_ratio(v: np.ndarray, y: np.ndarray, n_fit: int) -> dict:
    """Held-out over fitting-part spread of the input, output and input rate at the cut
    ``n_fit``, and their minimum (``"ratio"``)."""
    fit, held = excitation(v[:n_fit], y[:n_fit]), excitation(v[n_fit:], y[n_fit:])
    ratios = {k: held[k] / fit[k] if fit[k] > 0 else (1.0 if held[k] == 0 else np.inf)
              for k in fit}
    return dict(ratios, ratio=float(min(ratios.values())))


def error_ratio(error: np.ndarray, n_fit: int) -> float:
    """Held-out over fitting-part mean squared ``error`` at the cut ``n_fit`` (NaN samples,
    a start-up transient, left out)."""
    fit, held = np.nanmean(error[:n_fit] ** 2), np.nanmean(error[n_fit:] ** 2)
    return float(held / fit) if fit > 0 else (1.0 if held == 0 else np.inf)


def choose_split(v, y, holdout: float, min_fit: int, min_hold: int = 50,
                 mode: str = "excited", error=None) -> tuple[int, dict]:
    """The number of fitting samples ``n_fit`` and a report of the choice.

    ``mode="tail"``: the last ``holdout`` fraction is held out, as requested.
    ``mode="excited"`` (the default of :func:`hbjax.diagnose`): the same unless the held-out
    part's excitation ratio is below :data:`MIN_RATIO`; then the cut moves earlier, up to a
    held-out fraction of :data:`MAX_FRACTION` (the fitting part keeps at least
    ``min_fit`` samples), to the first cut whose ratio reaches :data:`MIN_RATIO`, else to
    the largest ratio (the requested cut when nothing is better). With ``error`` (the
    nominal model's free-run error, NaN where it is left out), cuts whose
    :func:`error_ratio` exceeds both :data:`MAX_ERROR_RATIO` and the requested cut's are
    skipped; the report then lists them (``"skipped_for_error"``: held-out fractions and
    their error ratios) with the limit (``"error_limit"``).
    """
    v, y = np.asarray(v, float), np.asarray(y, float)
    n = len(v)
    requested = n - int(round(holdout * n))
    first = excitation_ratio(v, y, requested)
    report = {"mode": mode, "requested_holdout": float(holdout), "requested_n_fit": requested,
              "requested_ratio": first, "moved": False}
    if mode == "tail" or first["ratio"] >= MIN_RATIO:
        return requested, dict(report, n_fit=requested, ratio=first)
    best_n, best = requested, first
    error = None if error is None else np.asarray(error, float)
    limit = None if error is None else max(MAX_ERROR_RATIO, error_ratio(error, requested))
    skipped = []
    fractions = np.arange(holdout + _STEP, max(MAX_FRACTION, holdout) + 1e-9, _STEP)
    for h in fractions:
        n_fit = n - int(round(h * n))
        if n_fit < min_fit or n - n_fit < min_hold:
            continue
        if limit is not None and (e := error_ratio(error, n_fit)) > limit:
            skipped.append({"holdout": float((n - n_fit) / n), "error_ratio": e})
            continue  # the mismatch would leave the fitting part
        r = excitation_ratio(v, y, n_fit)
        if r["ratio"] > best["ratio"] + 1e-12:
            best_n, best = n_fit, r
        if r["ratio"] >= MIN_RATIO:  # the smallest move that is excited enough
            break
    if limit is not None:
        report.update(error_limit=float(limit), skipped_for_error=skipped)
    return best_n, dict(report, n_fit=best_n, ratio=best, moved=best_n != requested,
                        holdout=float((n - best_n) / n))
