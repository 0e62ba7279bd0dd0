"""The diagnosis's verdict: one of three plain statements about a recording.

- ``"consistent"``: no finding, and the nominal model's residual tests pass (the one-step
  prediction error is white and independent of past inputs at the :data:`REJECT_P` level):
  the recording is the nominal model up to white equation error.
- ``"explained"``: at least one finding: a mechanism that improves the **held-out free-run
  simulation** significantly (or, for a mechanism a noise model can mimic, its held-out
  one-step prediction while beating that noise model in BIC: ``noise_rival``), or (at most) a
  noise-model finding (``colored_noise``) that improves the held-out one-step prediction.
- ``"unexplained"``: no finding, but a residual test rejects; or only noise-model findings,
  whose own (whitened) one-step errors the input still predicts
  (``tests["independence_after_noise_model"]`` rejects: a noise model cannot explain an
  effect of the input). The structure is real, the library has no mechanism for it; the
  report names the rejecting tests and the regime variable (output level, input level,
  input rate, motion direction, time) whose bins explain most of the nominal simulation
  residual: where to look.

A candidate whose fit did not produce finite numbers (parameters, criterion, or free run)
is a **failed** candidate, listed with the reason; it is never reported or ranked.
"""

from __future__ import annotations

import math

import numpy as np

#: p-value below which whiteness / independence of the nominal residual is rejected
REJECT_P = 1e-3
#: regime tests of the residual analysis and the variable each one bins by
REGIMES = {"regime_output": "output level", "regime_input": "input level",
           "regime_rate": "input rate", "regime_direction": "motion direction",
           "regime_time": "time"}
VERDICTS = ("consistent", "explained", "unexplained")


def rejected_tests(tests: dict) -> list[str]:
    """Names of the classical residual tests that reject at :data:`REJECT_P`."""
    out = []
    for name in ("whiteness", "independence"):
        p = tests.get(name, {}).get("p_value")
        if p is not None and (not math.isfinite(float(p)) or float(p) < REJECT_P):
            out.append(name)
    return out


def regime_driver(tests: dict) -> dict | None:
    """The regime variable whose bins explain the largest share of the nominal simulation
    residual's variance: ``{"variable", "test", "explained", "worst_range"}``."""
    rows = [(name, tests[name]) for name in REGIMES if name in tests]
    if not rows:
        return None
    name, row = max(rows, key=lambda r: r[1]["explained"])
    return {"variable": REGIMES[name], "test": name, "explained": float(row["explained"]),
            "worst_range": row.get("worst_range")}


def verdict(findings: list, tests: dict) -> tuple[str, dict]:
    """``(verdict, detail)``; ``detail`` holds ``rejected`` (test names) and ``regime``
    (see :func:`regime_driver`)."""
    rejected = rejected_tests(tests)
    detail = {"rejected": rejected, "regime": regime_driver(tests)}
    after = tests.get("independence_after_noise_model")
    if after is not None and not float(after["p_value"]) >= REJECT_P:
        detail["rejected"] = ["independence after the noise model"]
        return "unexplained", detail
    if findings:
        return "explained", detail
    if rejected:
        return "unexplained", detail
    return "consistent", detail


def sentence(verdict_: str, detail: dict, findings: list) -> str:
    """The verdict as one plain sentence for :meth:`hbjax.Diagnosis.summary`."""
    if verdict_ == "explained":
        f = findings[0]
        if not f.mechanism:
            kind = "a noise-model finding (held-out one-step prediction)"
        elif f.metric == "prediction":
            kind = "a mechanism the free run cannot show: held-out one-step prediction"
        else:
            kind = "held-out free-run simulation"
        return (f"Verdict: explained. {f.effect} accounts for the mismatch ({kind} fit "
                f"{f.fit_before:.1f}% -> {f.fit_after:.1f}%).")
    if verdict_ == "consistent":
        return ("Verdict: consistent. The residual tests pass and no candidate improves the "
                "held-out simulation: the recording is the nominal model up to white equation "
                "error.")
    reg = detail.get("regime")
    where = ""
    if reg is not None:
        lo, hi = (reg.get("worst_range") or [None, None])[:2]
        # The output level is binned on the nominal free run (binning on the recorded
        # output would sort the residual by itself), so its range is the free run's.
        on = (" where the nominal free run is in" if reg.get("test") == "regime_output"
              else " in")
        rng = f", largest{on} {lo:.4g}..{hi:.4g}" if lo is not None and hi is not None else ""
        where = (f" The {reg['variable']} explains most of the nominal residual "
                 f"({100 * reg['explained']:.0f}% of its variance by bins{rng}).")
    rejected = detail.get("rejected") or []
    if rejected == ["independence after the noise model"]:
        return (f"Verdict: structured but unexplained. A noise model improves the one-step "
                f"prediction, but the input still predicts its whitened errors (independence "
                f"p < {REJECT_P:g}), which no noise model can explain, and no mechanism of the "
                f"library improves the held-out free-run simulation significantly.{where}")
    tests = (" and ".join(rejected) + (" tests reject" if len(rejected) > 1 else " test rejects")
             if rejected else "residual tests reject")
    return (f"Verdict: structured but unexplained. The {tests} (p < {REJECT_P:g}) "
            f"but no mechanism of the library improves the held-out free-run simulation "
            f"significantly.{where}")


def failure(stat: dict, theta, params=None) -> str | None:
    """Why a fitted candidate failed (``None`` if it did not): non-finite parameters,
    criterion or free run."""
    # (open clip levels are +-inf by design: only NaN marks a broken parameter)
    arrays = [np.asarray(theta, float)] + ([np.asarray(params, float)] if params is not None
                                          else [])
    if any(np.any(np.isnan(a)) for a in arrays):
        return "the fit ended at NaN parameters"
    if not math.isfinite(float(stat.get("sse", np.nan))):
        return "the fitting criterion is not finite at the fitted parameters"
    if not math.isfinite(float(stat.get("fit_sim", np.nan))):
        return "the free-run simulation of the fitted model diverges (non-finite output)"
    return None
