"""`fit`'s default criterion, ``"auto"``: the equation-error criterion where its noise
assumption holds, the output-error criterion where the records reject it.

The prediction criterion is the maximum-likelihood criterion of the paper's model with the
noise in the equation, eq. (10): ``A(q^-1) y = B(q^-1) u + xi`` with ``xi`` white (A6).
Noise at the sensor instead, ``y = y_0 + w``, reaches the one-step errors as
``A(q^-1) w``: coloured, and correlated with the lagged outputs the predictor regresses on,
so the estimate is biased (errors in variables) and its free run misses. The simulation
criterion (output error) is consistent under either noise, independent of the input, but
less efficient under equation noise. The two are told apart by residual whiteness
(Ljung-Box over 25 lags, all records pooled, as :func:`hbjax.resid`):

1. the prediction optimum's one-step errors coloured at :data:`COLOURED_P`: the optimum is
   refined once more with the simulation criterion (:func:`hbjax.refine`, started from
   it, no restarts) and judged as `fit` judges its best start, the starts are searched
   with that criterion too, and the one of the two with the lower cost is reported where
   it is a success (one refinement from a biased optimum can stop at a worse optimum than
   the starts reach; a success at a higher cost than a refused optimum is a local
   minimum, :func:`_better`);
2. white: that refinement runs too, and is reported where *its* free-run errors are white
   and its one-step errors coloured (:func:`noise_at_output`): under sensor noise the
   prediction optimum's biased ``a``, pulled towards 0, whitens its own one-step errors,
   so the consistent output-error optimum reads the noise instead; then as in 1, and
   where neither output-error result succeeds, the refusal is reported: the biased
   optimum is no success either;
3. otherwise the prediction result stands.

Where the prediction criterion's search finds no success at all (unstable, below the
free-run floor, an unresolved loop: what its bias under sensor noise can produce), the
starts are searched again with the simulation criterion, whose success is reported only
where the noise is not the equation's by the same two readings
(:func:`search_after_failure`).

Measured (10 random paper-class systems of ``tests/generators/paper_class.py`` at noise
1, 3 and 10 % of the output's range, validation on a fresh noise-free record): with the
noise in the equation the prediction result stood in all 30 runs; with it at the output
the switch happened in 21 of 30 and raised the lowest validation fits from 29 / 58 / 21 %
to 99.6 / 97.3 / 91.2 % (the whiteness test alone). At 5 and 20 % sensor noise (8 systems,
2000 samples) the rule above reaches the simulation criterion's lowest validation fits
(89.8 and 84.2 %), where the whiteness test alone had kept a success validating at -3.6 %;
under equation noise it kept the prediction criterion in 16 of 16. ``benchmarks/RESULTS.md``,
"fit's criterion chosen from the records" and the section after it.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .._misc import chi2_sf
from .._results import RESULTS
from .adequacy import LAGS, _centred, _ljung_box, _one_step, _rounding, whiteness_p
from .compare import compare, play_state_for_prediction
from .criteria import PREDICTION

#: ``fit``'s default criterion: chosen from the records (this module).
AUTO = "auto"
#: Ljung-Box p-value of the prediction optimum's one-step errors below which the
#: equation-error model is rejected and the output-error criterion is used.
COLOURED_P = 1e-3
#: Ljung-Box p-value at or above which the output-error optimum's free-run errors read as
#: white in :func:`noise_at_output`: the residual tests' usual 1 % level, stricter than
#: :data:`COLOURED_P`, so that neither reading decides on a borderline p (a 300-sample
#: record with equation noise gave p = 0.0016 there and was misread as sensor noise).
WHITE_P = 0.01
#: Fewest one-step errors a record needs to enter the test (twice its lags, as
#: :func:`hbjax.resid` cuts them): a shorter record's autocorrelations are 0 / 0.
MIN_ERRORS = 2 * LAGS + 1

#: The statements `criterion_choice` makes (a static field: a fixed vocabulary, the
#: p-value is `prediction_whiteness_p`).
WHITE = "auto: prediction (its one-step errors are white)"
NOISE_FREE = "auto: prediction (its one-step errors are rounding: noise-free records)"
TOO_SHORT = "auto: prediction (no record long enough for the whiteness test)"
ADOPTED = ("auto: simulation (output error), {}, the prediction optimum's one-step errors "
           "being coloured: noise at the output, or dynamics the model lacks")
KEPT = ("auto: prediction kept; its one-step errors are coloured, but the output-error "
        "criterion gave no success ({})")
SENSOR = ("auto: simulation (output error), {}: the output-error optimum's free-run "
          "errors are white and its one-step errors coloured, noise at the sensor (which "
          "biases the prediction criterion, whose own errors looked white)")
SENSOR_REFUSED = ("auto: simulation (output error): the refinement from the prediction "
                  "optimum reads noise at the sensor (free-run errors white, one-step errors "
                  "coloured), which biases that optimum; the output-error criterion gave "
                  "no success ({}), so neither does the biased optimum")
SEARCHED = ("auto: simulation (output error), from its own multi-start search: the "
            "prediction criterion's search found no success ({}) and the noise is not the "
            "equation's")
BOTH_FAILED = ("auto: prediction; no start succeeded with it (its one-step errors are "
               "coloured), nor with the output-error criterion's own search ({})")
FAILED_WHITE = ("auto: prediction; no start succeeded, and the noise reads as the "
                "equation's (the equation-error model holds): the output-error search's "
                "result was not taken")
AS_ASKED = ("prediction, as asked; its one-step errors are coloured: with noise at the "
            "sensor this criterion is biased (criterion='auto' or 'simulation' fits the free "
            "run), or the model lacks dynamics")


#: Failures that say the records' inputs do not determine the branches (too few distinct
#: values where a branch decides the output), whatever the criterion.
UNDETERMINED = (RESULTS.branches_undetermined, RESULTS.branches_between_levels)


def worth_output_error_search(res) -> bool:
    """Whether the prediction criterion's search (`res`, concrete) found no success for a
    reason other than inputs that do not determine the branches (:data:`UNDETERMINED`):
    then ``"auto"`` tests its optimum's one-step errors (:func:`search_after_failure`)."""
    return (res.criterion == PREDICTION and res.result != RESULTS.successful
            and not any(res.result == code for code in UNDETERMINED))


def search_after_failure(res, recordings, *, initial_state, search_output_error):
    """`res` (the prediction criterion's failure, concrete) as ``"auto"`` reports it.

    The starts are searched again with the output-error criterion,
    ``search_output_error()``, and its success is reported where the noise is not the
    equation's: the prediction optimum's one-step errors are coloured, or the output-error
    optimum reads the noise as the sensor's (:func:`noise_at_output`). Under sensor noise
    the equation-error optimum's bias can leave it unstable, below the free-run floor or
    with its loop unresolved. Where neither holds, the equation-error model stands, its
    failure is the records' (an unresolved loop, no significant input path) and `res` is
    reported, saying so: on closing loops under equation noise the output-error search
    turned eight such refusals into successes validating at 90-99 %, five of them local
    minima."""
    p, untested = prediction_whiteness(res.model, recordings, initial_state)
    res = dataclasses.replace(res, prediction_whiteness_p=jnp.asarray(p))
    searched = search_output_error()
    if searched.result == RESULTS.successful and (
            p < COLOURED_P or noise_at_output(searched.model, recordings, initial_state)):
        return dataclasses.replace(searched, prediction_whiteness_p=jnp.asarray(p),
                                   criterion_choice=SEARCHED.format(res.message.rstrip(".")))
    if searched.result == RESULTS.successful or not p < COLOURED_P:
        return dataclasses.replace(res, criterion_choice=untested or FAILED_WHITE)
    return dataclasses.replace(res, criterion_choice=BOTH_FAILED.format(
        searched.message.rstrip(".")))


def prediction_whiteness(model, recordings, initial_state: str) -> tuple[float, str]:
    """Ljung-Box p-value (records pooled) of `model`'s one-step prediction errors, each
    record's play operator started as :func:`hbjax.resid` starts it (with
    ``"estimate"``: the state in the band at the first input whose predictions fit best;
    a record that starts at rest away from zero otherwise keeps a wrong internal signal
    until its input leaves the band, and the errors of a true model look coloured).
    Returns ``(p, note)``: ``note`` is ``None`` where the test ran; else ``p`` is NaN and
    the note says why not: no record holds :data:`MIN_ERRORS` errors (shorter ones are
    left out), or the errors are rounding (:func:`_rounding`: a noise-free record's
    one-step errors are "coloured" by the arithmetic alone)."""
    skip = max(model.arx.na, model.arx.nb)
    recordings = [tuple(jnp.asarray(a) for a in rec) for rec in recordings]
    recordings = [(v, y) for v, y in recordings if v.shape[0] - skip >= MIN_ERRORS]
    if not recordings:
        return float("nan"), TOO_SHORT
    sources, ssr, spread = [], 0.0, 0.0
    for v, y in recordings:
        u0 = (play_state_for_prediction(model, model, v, y, skip)
              if initial_state == "estimate" else 0.0)
        u = model.free_run(v, jnp.zeros_like(v), u0)[0]
        sources.append(u)
        e, _, _ = _one_step(model, v, y, u, None)  # zero over the first `skip` samples
        ssr += float(jnp.sum(e**2))
        spread += float(jnp.sum((y[skip:] - jnp.mean(y[skip:])) ** 2))
    if ssr <= float(_rounding(spread, recordings[0][1].dtype)):
        return float("nan"), NOISE_FREE
    return float(whiteness_p(model, recordings, sources)[0]), None


def free_run_whiteness(model, recordings, initial_state: str) -> float:
    """Ljung-Box p-value (records pooled, :data:`LAGS` lags each) of `model`'s free-run
    errors ``y - y_sim`` (:func:`hbjax.compare`'s free run, from the initial state it
    estimates with ``"estimate"``); records shorter than :data:`MIN_ERRORS` left out (NaN
    where none is left)."""
    q, dof = 0.0, 0
    for v, y in recordings:
        v, y = jnp.asarray(v), jnp.asarray(y)
        if v.shape[0] < MIN_ERRORS:
            continue
        y_hat = jnp.asarray(compare(model, v, y, initial_state=initial_state).y_hat)
        e = y - jnp.reshape(y_hat, y.shape)
        n = jnp.asarray(float(y.shape[0]), y.dtype)
        q += float(_ljung_box(_centred(e, jnp.ones(y.shape, bool), n), n, LAGS))
        dof += LAGS
    return float(chi2_sf(q, dof)) if dof else float("nan")


def noise_at_output(model, recordings, initial_state: str) -> bool:
    """Whether `model` (an output-error optimum: consistent whether the noise is in the
    equation or at the output) reads the records' noise as the sensor's: its free-run
    errors white (p >= :data:`WHITE_P`) and its one-step errors coloured
    (p < :data:`COLOURED_P`). Noise in the
    equation, ``xi``, gives the reverse (one-step errors ``xi``, free-run errors
    ``xi / A``). The prediction optimum cannot tell: under sensor noise its biased ``A``,
    pulled towards 0, whitens its own one-step errors (measured: 20 % sensor noise kept the
    prediction criterion with validation fits of -3.6 and 92.9 % where the output-error
    search reached 97.8 %)."""
    one_step, untested = prediction_whiteness(model, recordings, initial_state)
    if untested is not None or not one_step < COLOURED_P:
        return False
    return free_run_whiteness(model, recordings, initial_state) >= WHITE_P


#: Refusals of a judged optimum (fit's judgements after the screen): such a result is a
#: model of the records whose cost competes with the other output-error result's.
_JUDGED = (RESULTS.loop_unresolved, RESULTS.branches_undetermined,
           RESULTS.branches_between_levels, RESULTS.free_run_undetermined)


def _better(out, searched, samples: int):
    """Of two output-error results (the refinement from the prediction optimum, judged by
    `fit`, and the output-error criterion's own multi-start search), the one `fit` would
    report had both been its starts: the lower cost (higher free-run fit on the records)
    among those that passed its screen (stable, a significant input path, above the
    floor), the refinement unless the search's cost is lower by more than ``2 sigma^2``
    (``sigma^2 = SSE / samples``: the same optimum within its noise); ``None`` where
    neither passed. Where the one returned is refused, the output-error criterion has no
    success: a success at a higher cost than a refused optimum is a local minimum
    (measured on a BRFD record: the refinement from the prediction optimum at 59.8 %
    free-run fit beside the search's 67.7 %, whose branches the record does not
    determine). One refinement from the biased prediction optimum can stop at a worse
    optimum than the starts reach: 75.1 against 89.8 % validation fit under 5 % sensor
    noise, 58-61 against 66-71 % free-run fit on the BRFD records."""
    screened = [r for r in (out, searched)
                if r.result == RESULTS.successful or any(r.result == c for c in _JUDGED)]
    if len(screened) < 2:
        return screened[0] if screened else None
    # the pooled fit's error norms: ||e|| = (1 - fit / 100) ||y - mean||, same records
    e_out, e_searched = (1.0 - float(r.sim_fit_pooled) / 100.0 for r in screened)
    return searched if e_out**2 > e_searched**2 * (1.0 + 2.0 / samples) else out


def _no_success(out, searched, best) -> str:
    """Why the output-error criterion gave no success: `best` (:func:`_better`) refused,
    and where the other result succeeded, that it stopped at a higher cost."""
    if best is None:
        return out.message
    other = searched if best is out else out
    if other.result != RESULTS.successful:
        return best.message
    name = {id(out): "the refinement from the prediction optimum",
            id(searched): "the output-error search"}
    return (f"{name[id(other)]} succeeded at {float(other.sim_fit_pooled):.1f} % free-run "
            f"fit, a local minimum: {name[id(best)]} reached "
            f"{float(best.sim_fit_pooled):.1f} %, refused: {best.message}")


def choose_criterion(res, recordings, *, initial_state, refine_output_error, adopt,
                     search_output_error=None, auto: bool = True):
    """`res` (the prediction criterion's :class:`hbjax.FitResult`, concrete) as `fit`
    reports it, with `prediction_whiteness_p` and `criterion_choice` set.

    With ``auto`` (the default criterion), where it is a success: the output-error
    refinement from its model, ``refine_output_error(model)`` (a
    :class:`hbjax.RefineResult`), made a fit result and judged by ``adopt(res, refined)``,
    or the output-error criterion's own search, ``search_output_error()`` (a
    :class:`hbjax.FitResult`), the lower-cost of the two where it succeeds
    (:func:`_better`), where
    either `res`'s one-step errors are coloured at :data:`COLOURED_P` or the refinement
    reads the noise as the sensor's (:func:`noise_at_output`); in the second case a
    refusal where neither succeeds (the prediction optimum is then biased and its
    covariance rests on a rejected noise model); `res`, saying why, otherwise. With
    ``auto=False`` (the prediction criterion asked for) the result is kept and
    `criterion_choice` notes coloured errors."""
    if res.criterion != PREDICTION or res.result != RESULTS.successful:
        return res
    p, untested = prediction_whiteness(res.model, recordings, initial_state)
    res = dataclasses.replace(res, prediction_whiteness_p=jnp.asarray(p))
    coloured = p < COLOURED_P  # (NaN: not tested, see the note)
    if not auto:
        return dataclasses.replace(res, criterion_choice=AS_ASKED) if coloured else res
    if untested:
        return dataclasses.replace(res, criterion_choice=untested)
    refined = refine_output_error(res.model)
    samples = sum(int(rec[1].shape[0]) for rec in recordings)
    if not coloured:
        # White errors may be the prediction optimum's bias whitening them: the
        # output-error refinement from it reads the noise (noise_at_output).
        if not (refined.result == RESULTS.successful
                and noise_at_output(refined.model, recordings, initial_state)):
            return dataclasses.replace(res, criterion_choice=WHITE)
        # The prediction optimum is then known to be biased, and its covariance to rest
        # on a noise model the records reject: where fit's judgements refuse the
        # consistent estimates, that refusal is the answer (measured: 20 % sensor noise,
        # a prediction "success" validating at -3.6 % beside an output-error optimum
        # whose free run the records do not determine).
        out = adopt(res, refined)
        searched = search_output_error()
        best = _better(out, searched, samples)
        if best is None or best.result != RESULTS.successful:
            return dataclasses.replace(
                best or out, prediction_whiteness_p=jnp.asarray(p),
                criterion_choice=SENSOR_REFUSED.format(_no_success(out, searched, best)))
        return dataclasses.replace(best, prediction_whiteness_p=jnp.asarray(p),
                                   criterion_choice=SENSOR.format(_how(best, searched)))
    out = adopt(res, refined) if refined.result == RESULTS.successful else refined
    searched = search_output_error()
    best = _better(out, searched, samples)
    if best is None or best.result != RESULTS.successful:
        return dataclasses.replace(res, criterion_choice=KEPT.format(
            _no_success(out, searched, best)))
    return dataclasses.replace(best, prediction_whiteness_p=jnp.asarray(p),
                               criterion_choice=ADOPTED.format(_how(best, searched)))


def _how(best, searched) -> str:
    return ("from its own multi-start search" if best is searched
            else "refined from the prediction optimum")
