"""`fit`'s default criterion, ``"auto"``: the equation-error criterion where its noise
assumption holds, the output-error criterion where the records reject it.

The prediction criterion is the maximum-likelihood criterion of the paper's model with the
noise in the equation, eq. (10): ``A(q^-1) y = B(q^-1) u + xi`` with ``xi`` white (A6).
Noise at the sensor instead, ``y = y_0 + w``, reaches the one-step errors as
``A(q^-1) w``: coloured, and correlated with the lagged outputs the predictor regresses on,
so the estimate is biased (errors in variables) and its free run misses. The simulation
criterion (output error) is consistent under either noise, independent of the input, but
less efficient under equation noise. The two are told apart by the whiteness test of the
prediction optimum's one-step errors (Ljung-Box over 25 lags, all records pooled, as
:func:`hbjax.resid`): white, the equation-error model holds and its result stands; coloured
at :data:`COLOURED_P`, the optimum is refined once more with the simulation criterion
(:func:`hbjax.refine`, started from it) and that result is reported where it is a success.

Measured (10 random paper-class systems of ``tests/generators/paper_class.py`` at noise
1, 3 and 10 % of the output's range, validation on a fresh noise-free record): with the
noise in the equation the prediction result stood in all 30 runs; with it at the output
the switch happened in 21 of 30 and raised the lowest validation fits from 29 / 58 / 21 %
to 99.6 / 97.3 / 91.2 %. ``benchmarks/RESULTS.md``, "fit's criterion chosen from the
records".
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .._results import RESULTS
from .adequacy import whiteness_p
from .compare import play_state_for_prediction
from .criteria import PREDICTION, SIMULATION

#: ``fit``'s default criterion: chosen from the records (this module).
AUTO = "auto"
#: Ljung-Box p-value of the prediction optimum's one-step errors below which the
#: equation-error model is rejected and the output-error criterion is used.
COLOURED_P = 1e-3


def prediction_whiteness(model, recordings, initial_state: str) -> float:
    """Ljung-Box p-value (records pooled) of `model`'s one-step prediction errors, each
    record's play operator started as :func:`hbjax.resid` starts it (with
    ``"estimate"``: the state in the band at the first input whose predictions fit best;
    a record that starts at rest away from zero otherwise keeps a wrong internal signal
    until its input leaves the band, and the errors of a true model look coloured)."""
    recordings = [tuple(jnp.asarray(a) for a in rec) for rec in recordings]
    skip = max(model.arx.na, model.arx.nb)
    sources = []
    for v, y in recordings:
        u0 = (play_state_for_prediction(model, model, v, y, skip)
              if initial_state == "estimate" else 0.0)
        sources.append(model.free_run(v, jnp.zeros_like(v), u0)[0])
    return float(whiteness_p(model, recordings, sources)[0])


def choose_criterion(res, recordings, *, initial_state, refine_output_error, adopt,
                     auto: bool = True):
    """`res` (the prediction criterion's :class:`hbjax.FitResult`, concrete) as ``"auto"``
    reports it: unchanged, with the whiteness it was judged on, where its one-step errors
    are white at :data:`COLOURED_P` (or it is not a success); otherwise the output-error
    refinement from its model, ``refine_output_error(model)`` (a
    :class:`hbjax.RefineResult`), made a fit result by ``adopt(res, refined)`` where that
    refinement succeeds. With ``auto=False`` (the prediction criterion asked for) the
    result is kept and, where its errors are coloured, `criterion_choice` says so."""
    if res.criterion != PREDICTION or res.result != RESULTS.successful:
        return res
    p = prediction_whiteness(res.model, recordings, initial_state)
    if not auto:
        return res if not p < COLOURED_P else dataclasses.replace(
            res, criterion_choice=(
                f"prediction, as asked; its one-step errors are coloured (p = {p:.2g}): "
                f"with noise at the sensor this criterion is biased (criterion='auto' or "
                f"'simulation' fits the free run), or the model lacks dynamics"))
    if not p < COLOURED_P:
        return dataclasses.replace(
            res, criterion_choice=f"auto: prediction (one-step errors white, p = {p:.2g})")
    refined = refine_output_error(res.model)
    if refined.result != RESULTS.successful:
        return dataclasses.replace(
            res, criterion_choice=(
                f"auto: prediction kept; its one-step errors are coloured (p = {p:.2g}), "
                f"but the output-error refinement from it failed ({refined.message})"))
    out = adopt(res, refined)
    return dataclasses.replace(
        out, criterion=SIMULATION, criterion_choice=(
            f"auto: simulation (output error), refined from the prediction optimum, whose "
            f"one-step errors are coloured (p = {p:.2g}): noise at the output, or dynamics "
            f"the model lacks"))
