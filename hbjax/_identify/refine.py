"""Prediction-error / output-error refinement of an HB-Hammerstein model with optimistix.

``refine`` minimises the sum of squared one-step prediction errors (the maximum-likelihood
criterion under the paper's Gaussian equation error, eq. (10)) or of output errors (free run)
over the normalised parameters, with Levenberg–Marquardt through the differentiable play
operator and ARX recursion. ``refine_traceable`` is its jit/vmap-able core.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._core.buckets import padded_records, should_bucket
from .._core.cache import ensure_compilation_cache
from .._core.model import Hammerstein
from .._core.params import flatten_params, gauge_factor, param_names
from .._core.precision import require_x64
from .._misc import (check_bool, is_real_scalar, is_traced, no_spread, positive_float,
                     positive_int)
from .._results import RESULTS, code, raise_if_failed
from .adequacy import LEVEL
from .centring import (at_better_start, in_recorded_coordinates, less_centres, refine_centres,
                       to_centred)
from .criteria import PREDICTION, SIMULATION, lower_is_p1, sample_count
from .fit_starts import canonical_result
from .quality import SIM_FIT_FLOOR
from .recordings import (as_recordings, check_branch_degree, check_criterion, check_h_m, check_model,
                         total_samples)
from .refine_band import best_of_core_start, labelled_from
from .loop import check_loop_tolerance, judge_loop
from .refine_kinks import escape_kinks, escape_pushed_through
from .refine_result import (RefinementError, RefineResult, at_estimated_start, finish,
                            summarise)
from .refine_solve import flat_residuals, gauge_transform, make_parametrisation
from .stable import check_estimated_start, check_initial_state
from .units import in_unit, model_in_unit, output_unit, result_from_unit

__all__ = ("RESULTS", "RefineResult", "RefinementError", "gauge_transform",
           "make_parametrisation", "refine", "refine_batch", "refine_traceable")


def refine_traceable(model: Hammerstein, recordings, *, criterion: str = "prediction",
                     h_m=None, max_steps: int = 256, rtol: float = 1e-7,
                     atol: float = 1e-7, statistics: bool = True,
                     min_sim_fit: float = SIM_FIT_FLOOR, initial_state: str = "zero",
                     stable: bool = False, core_start: bool = True,
                     core_only=False) -> RefineResult:
    """Traceable core of :func:`refine`: no checks, never raises, result code in `.result`.

    ``stable=True`` searches within the stable linear blocks only (``A`` through its
    reflection coefficients, :mod:`hbjax._identify.stable`; an unstable start is projected
    onto them); the covariance is then that of the usual parameters at the optimum.

    With ``statistics=True`` (default) the prediction criterion is solved on the Gram matrix
    of its bilinear regressors, one pass over the data per round (:mod:`hbjax._identify.sufficient`),
    with the full solve as fallback, for orders whose Gram matrix is small
    (``1 + na + 2 m nb <= 32``); ``statistics=False`` always takes a pass per
    Levenberg–Marquardt step (used by multi-start fitting under ``vmap``, where the
    fallback's ``lax.cond`` would run both branches).

    Two stages: the labelled band (:func:`hbjax._identify.criteria._internal`) from the
    start; then, only if its optimum's play-operator output differs from the core
    operator's on the data (an extrapolated branch crossing the active one where that
    decides the output), the core operator ``L = min, H = max`` from there, so that the
    returned model's fit is always the fit of :func:`hbjax.simulate`'s model.

    ``core_start=True`` (the default, what :func:`refine` does) also solves on the core
    operator from the start itself and keeps the better of the two optima
    (:func:`hbjax._identify.refine_band.best_of_core_start`); multi-start fitting turns
    it off (each start is cheap and many). The labelled solve alone can end far from a
    good start: on the paper's design at ``N = 200`` and noise std 0.3 it ended at 8
    times the closed form's prediction error, refused as ``no_input_effect``, in 7 of 16
    realisations, where with the core start none failed (``benchmarks/RESULTS.md``,
    "Three more probes"). ``core_only`` (a bool, or a traced boolean:
    one compiled solve serves both) solves on the core operator from the start instead of
    the labelled band (multi-start fitting's starts whose loop closes inside the data).

    ``recordings`` must already be a tuple of ``(v, y)`` float64 array pairs, or of padded
    records ``(v, y, n)`` (zero-padded to a bucket length, ``n`` recorded samples as an
    integer array; :func:`hbjax._identify.criteria.unpack`), which give the unpadded
    records' results from one program per bucket. Works under
    ``jax.jit`` and ``jax.vmap`` (e.g. over noise realisations with the inputs shared);
    see :func:`refine_batch`.

    The solve runs on the outputs in their own unit (:mod:`hbjax._identify.units`), so
    that its tolerances and the covariance do not depend on the unit of ``y``.
    """
    unit = output_unit(recordings)
    res = _refine_in_unit(model_in_unit(model, unit), in_unit(recordings, unit),
                          criterion=criterion, h_m=h_m, max_steps=max_steps, rtol=rtol,
                          atol=atol, statistics=statistics, min_sim_fit=min_sim_fit,
                          initial_state=initial_state, stable=stable, core_start=core_start,
                          core_only=core_only)
    res = result_from_unit(res, unit)
    # On the core operator the labels are interchangeable (L = min, H = max): a solve may
    # end with P1 and P2 exchanged, the same model under the other names. Under the
    # static-gain gauge the names are put back (P1 the branch a rising input drives onto);
    # the paper's gauge P2(-h_m) - P1(h_m) = 1 names the branches itself.
    return canonical_result(res, recordings) if res.gauge == "static_gain" else res


def _refine_in_unit(model, recordings, *, criterion, h_m, max_steps, rtol, atol, statistics,
                    min_sim_fit, initial_state, stable, core_start, core_only):
    par = make_parametrisation(model, recordings, h_m, stable=stable,
                               initial_state=initial_state)
    start, ok = gauge_transform(model, par)
    # The band's orientation is taken from the (normalised) start and kept fixed.
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower_is_p1(start, recordings))
    z0 = par.free(flatten_params(start))
    options = dict(max_steps=max_steps, rtol=rtol, atol=atol)
    if core_only is not False:
        par = eqx.tree_at(lambda p: p.core, par, jnp.asarray(core_only))
    if core_start:
        par, z, result, steps, ssr, ssr0, jtj = best_of_core_start(
            par, z0, recordings, criterion, statistics, options)
    else:
        par, z, result, steps, ssr, ssr0, jtj = labelled_from(par, z0, recordings, criterion,
                                                              statistics, options)
    if stable:
        # Back to the affine parameters (a itself) for the covariance and the checks.
        theta = par.theta(z)
        par = dataclasses.replace(par, stable=False)
        z = par.free(theta)
        jac = jax.jacfwd(flat_residuals)(z, par, recordings, criterion)
        jtj = jac.T @ jac
    n = sample_count(recordings)
    fitted, result, stats, cov, noise_std = summarise(par, z, ssr, ssr0, jtj, n, result,
                                                      steps, ok)
    return finish(fitted, result, stats, cov, noise_std, par, recordings, criterion, jtj,
                  min_sim_fit)


# `jax.jit` rather than `eqx.filter_jit`: its C++ dispatch path takes microseconds where
# filter_jit's flattening and filtering in Python took about 0.6 ms of a 7 ms refinement.
# The solver's options are static as filter_jit made them (Python scalars and strings);
# the model, the records, `h_m` (an array or None) and the floor (a number or a tracer,
# only compared with the fit) are runtime values.
@functools.partial(jax.jit, static_argnames=("criterion", "max_steps", "rtol", "atol",
                                             "initial_state"))
def _refine_jit(model, recordings, criterion, h_m, max_steps, rtol, atol, min_sim_fit,
                initial_state="zero"):
    return refine_traceable(model, recordings, criterion=criterion, h_m=h_m,
                            max_steps=max_steps, rtol=rtol, atol=atol,
                            min_sim_fit=min_sim_fit, initial_state=initial_state,
                            core_start=True)


@eqx.filter_jit
def refine_batch(models: Hammerstein, inputs, outputs, *, criterion: str = "prediction",
                 h_m=None, max_steps: int = 256, rtol: float = 1e-7, atol: float = 1e-7,
                 batch_size: int | None = None) -> RefineResult:
    """:func:`refine_traceable` over a batch of initial models and output records that
    share their input records, compiled once per shape; never raises.

    **Arguments:** `models` (a Hammerstein whose leaves have a leading batch axis ``R``),
    `inputs` (tuple of input records ``v_k``, shape ``(T_k,)``), `outputs` (tuple of
    output records ``y_k``, shape ``(R, T_k)``), `batch_size` (``None``: one fit after the
    other inside one compiled ``lax.map``; ``k``: ``vmap`` over groups of ``k``); other
    options as :func:`refine`. Unlike :func:`refine`, the records are solved as given (no
    centring of records far from zero, :mod:`hbjax._identify.centring`; the initial state
    from rest): take such offsets out first.

    On CPU the sequential map is about 3x faster per fit than ``vmap`` (measured in
    ``benchmarks/refine.py``): one fit's Jacobian (``T x p``) stays in cache, a batch's
    does not. On an accelerator pass a `batch_size`.

    **Returns:** a :class:`RefineResult` whose leaves have the leading axis ``R``.
    """

    def one(args):
        model, ys = args
        recs = tuple(zip(inputs, ys))
        return refine_traceable(model, recs, criterion=criterion, h_m=h_m,
                                max_steps=max_steps, rtol=rtol, atol=atol)

    return jax.lax.map(one, (models, tuple(outputs)), batch_size=batch_size)


def check_floor(min_sim_fit):
    """``min_sim_fit``: a finite real number (percent; may be negative, below 100: no fit
    reaches 100 % on noisy records) or a traced value."""
    if is_traced(min_sim_fit):
        return min_sim_fit
    if not is_real_scalar(min_sim_fit) or not np.isfinite(min_sim_fit) or not min_sim_fit < 100:
        raise ValueError("`min_sim_fit` must be a finite number (percent) below 100, got "
                         f"{min_sim_fit!r}: a free-run fit is at most 100 %.")
    return float(min_sim_fit)


def check_simulation_start(model, criterion) -> None:
    """The simulation criterion's free run diverges from an unstable ``A`` (assumption
    A3): its residuals overflow before the first step, so such a start is refused here
    rather than by the linear solver's non-finite output."""
    if criterion != SIMULATION or is_traced(model.arx.a):
        return
    radius = model.arx.pole_radius()
    if not radius < 1.0:
        raise ValueError(
            f"`model` has an unstable A (largest pole modulus {radius:.6g}, assumption A3): "
            "its free run diverges, so the simulation criterion cannot start from it. Start "
            "from a stable model: refine with criterion='prediction' first, or hbjax.fit, "
            "which searches within stable models.")


def check_gauge(model, h_m):
    if h_m is None:
        gain = float(np.sum(np.asarray(model.arx.b)))
        if gain == 0.0 or not np.isfinite(gain):
            raise ValueError(
                "the initial `model` has B(1) = sum(b) = 0: the static-gain normalisation "
                "B(1) = 1 used without `h_m` cannot be applied (assumption A5); pass `h_m` "
                "to use the paper's normalisation instead."
            )
        return
    bl = model.backlash
    if is_traced(h_m):
        return
    # A concrete model and h_m (checked above): computed in NumPy, no JAX dispatch.
    mu = float(gauge_factor(np.asarray(bl.c1), np.asarray(bl.c2), float(h_m)))
    if mu == 0.0 or not np.isfinite(mu):
        raise ValueError(
            f"mu = P2(-h_m) - P1(h_m) is {mu} for the initial `model` and `h_m` = {h_m}: "
            "the paper's normalisation (section 4.1) cannot be applied; the +-h_m swing "
            "must cross the backlash gap."
        )


# refine's default random starts where its result fails or its errors fail the residual
# tests: on the paper mode's far closed-form starts that ended in branches_cross,
# no_input_effect or a local minimum reported as success, 16 starts reached the true
# system's cost (tests/test_refine_restarts.py; benchmarks/paper_local_minima.py: 9 of 9).
AUTO_RESTARTS = 16


def residuals_suspect(res, records, criterion) -> bool:
    """Whether a refinement may have stopped short of the optimum: it is not a success, or
    (prediction criterion) its one-step errors fail :func:`hbjax.resid`'s whiteness or
    independence test on a record (Bonferroni over the ``2 x records`` tests)."""
    if int(code(res.result)) != int(code(RESULTS.successful)):
        return True
    if criterion != PREDICTION:
        return False
    from .residual_analysis import resid  # (NumPy report; imported where it is used)

    level = LEVEL / (2 * len(records))
    n_lags = max(res.model.arx.na, res.model.arx.nb)
    for v, y in records:
        # resid's 25 lags need 51 residuals; a shorter record is tested on fewer lags
        lags = min(25, (int(np.shape(v)[0]) - n_lags - 1) // 2)
        if lags < 1:
            continue
        # (the play state its criterion starts from: the convention's)
        r = resid(res.model, np.asarray(v), np.asarray(y), lags=lags, initial_state="zero")
        # (an input that never varies leaves independence untested: NaN, not a rejection)
        if not (r.p_whiteness >= level and not r.p_independence < level):
            return True
    return False


def startup_suspect(res, records) -> bool:
    """Whether the one-step errors of some record's first ``2 (n + 1)`` samples are too
    large for the noise: the largest of them over the records' RMS error beyond the normal
    quantile ``1 - LEVEL / (2 K)`` of their count ``K`` (prediction criterion, records
    from rest).

    There the initial state decides the prediction: the zero output lags and the play
    operator's state ``u0``, which the input moves onto a branch only where that branch
    passes it. The cost is flat in a branch value at an input where the play holds its
    state, so a refinement can end with the play held where the records show it moved
    (or the reverse), and then the first samples' errors carry the difference. Measured
    on the paper mode with the noise at the output (``benchmarks/identify_random.py
    --noise-at output``, seeds 3 and 7): three of the four local minima reported as
    success (33-44 ``sigma^2`` above the true system's cost, every whiteness and
    independence test passed) had an error of 4.6-7.0 RMS among the first samples of
    the constant-input record (this test's threshold there: 3.6), and 16 restarts
    reached the optimum on each."""
    from scipy.stats import norm  # (scipy: a dependency of the residual tests too)

    from .._core.simulate import predict

    n = max(res.model.arx.na, res.model.arx.nb)
    head, total, count = [], 0.0, 0
    for v, y in records:
        e = np.asarray(y) - np.asarray(predict(res.model, v, y))
        total += float(np.sum(e**2))
        count += e.size
        head.append(np.abs(e[:2 * (n + 1)]))
    head = np.concatenate(head)
    rms = np.sqrt(total / max(count, 1))
    if not (np.isfinite(rms) and rms > 0):
        return False
    return bool(np.max(head) / rms > norm.ppf(1.0 - LEVEL / (2 * head.size)))


def _restarted(res, records, recs, restarts, options):
    """:func:`refine`'s result, or the refinement of a multi-start fit's optimum where that
    is a success with a lower cost (see `restarts` in :func:`refine`)."""
    # fit refines through this module: imported here, where the two meet.
    from .fit import fit_unnoted, normalise_static_gain
    from .giri import normalise

    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    if all(no_spread(np.asarray(y)) for _, y in records):
        return res  # (fit refuses outputs that never move: nothing for its starts to find)
    alternative = fit_unnoted(
        records, na=na, nb=nb, m=m, key=jax.random.PRNGKey(0), starts=restarts,
        criterion=options["criterion"], initial_state=options["initial_state"],
        min_sim_fit=options["min_sim_fit"], loop_tolerance=float("inf"), throw=False,
        progress=False)
    # (fit's own judgements of undetermined branches and free runs are not refine's:
    # refine reports the flags and the covariance)
    if int(code(alternative.result)) not in (int(code(RESULTS.successful)),
                                             int(code(RESULTS.branches_undetermined)),
                                             int(code(RESULTS.branches_between_levels)),
                                             int(code(RESULTS.free_run_undetermined))):
        return res
    h_m = options["h_m"]
    start = normalise_static_gain(alternative.model) if h_m is None else normalise(
        alternative.model, h_m)
    again = _refine_jit(start, recs, **options)
    better = int(code(again.result)) == int(code(RESULTS.successful)) and (
        int(code(res.result)) != int(code(RESULTS.successful))
        or float(again.stats["cost"]) < float(res.stats["cost"]))
    return again if better else res


def _refine_at(model, recs, centres, options, restarts, loop_tolerance):
    """:func:`refine`'s solve, escapes, restarts and loop judgement on the records less
    `centres`, reported on the records as recorded."""
    criterion, initial_state = options["criterion"], options["initial_state"]
    h_m, min_sim_fit = options["h_m"], options["min_sim_fit"]
    recorded = recs
    moved = any(is_traced(c) or float(c) != 0.0 for c in centres)
    if not any(map(is_traced, centres)):
        centres = tuple(np.float64(c) for c in centres)  # (NumPy records stay on the host)
    if moved:
        recs = less_centres(recs, *centres)
        model = to_centred(model, *centres)
    records = recs
    if should_bucket(model, recs, h_m, min_sim_fit):
        # One program per bucket of record lengths; the padding is masked out of every sum.
        recs = padded_records(recs)
    res = _refine_jit(model, recs, **options)
    if not is_traced(res.result._value) and int(code(res.result)) in (
            int(code(RESULTS.successful)), int(code(RESULTS.branches_cross))):
        again = lambda start: _refine_jit(start, recs, **options)  # noqa: E731
        res = escape_pushed_through(escape_kinks(res, records, again), records, again)
    if restarts and not is_traced(res.result._value) and (
            residuals_suspect(res, records, criterion)
            or (criterion == PREDICTION and initial_state == "zero"
                and startup_suspect(res, records))):
        res = _restarted(res, records, recs, restarts, options)
    # on the bucket-padded records: a record of a new length compiles nothing new
    res = judge_loop(res, recs, loop_tolerance)
    if moved:
        res = in_recorded_coordinates(res, *centres)
    if initial_state == "estimate" and not is_traced(res.result._value):
        res = at_estimated_start(res, recorded)
    return res


def refine(model: Hammerstein, recordings, *, criterion: str = "prediction", h_m=None,
           max_steps: int = 256, rtol: float = 1e-7, atol: float = 1e-7,
           min_sim_fit: float = SIM_FIT_FLOOR, initial_state: str = "zero",
           restarts: int = AUTO_RESTARTS, loop_tolerance: float = float("inf"),
           throw: bool = True) -> RefineResult:
    """Refine an HB-Hammerstein model on recorded data by nonlinear least squares.

    Minimises, with :class:`optimistix.LevenbergMarquardt` through the differentiable
    play operator (``u(-1) = 0``, zero initial conditions as in :func:`hbjax.simulate`):

    - ``criterion="prediction"``: one-step prediction errors ``y(t) - y_hat(t)`` of
      eq. (10), the maximum-likelihood criterion under the paper's Gaussian equation error
      ``xi`` (it reaches the Cramér–Rao bound, :func:`hbjax.crlb`);
    - ``criterion="simulation"``: output errors ``y(t) - y_sim(t)`` (free run), consistent
      when white noise is added to the output instead (where the prediction criterion and
      the closed form are biased).

    The gain ambiguity ``(A, mu B, P/mu)`` is fixed by one linear equality, eliminated
    from the free parameters:

    - with `h_m`: the paper's ``P2(-h_m) - P1(h_m) = 1`` (section 4.1, as
      :func:`hbjax.normalise`); compare with ``hbjax.normalise(true_model, h_m)``;
    - without: the static gain of the numerator ``B(1) = sum(b) = 1`` (all the gain in the
      backlash, assumption A5 makes it possible); compare with
      :func:`hbjax.normalise_static_gain`.

    The band: the solve starts on a labelled band (the branch that is lower on average
    over the data for the normalised initial model is the lower edge ``L``; where an
    iterate's branches cross the output follows the branch of the input's direction of
    motion), smooth in the parameters and free of the spurious minima that sorting the
    closed form's crossed extrapolations causes. A branch's values where it never decides
    the output (the other side of the paper's staircase) are extrapolations and may cross
    the other branch freely; only where a crossing changes the output of the core operator
    ``L = min(P1, P2)``, ``H = max(P1, P2)`` on the data does the solve finish on the core
    operator from there. The core operator is also solved from the start itself and the
    better of the two converged optima is kept: from a start that is a band at every
    recorded input (the closed form keeps its branches one at the design's inputs,
    ``GiriResult.band_shift``) the core solve stays a band and reaches the optimum where the
    labelled one can end in a poor local optimum. Where the result (a success, or
    ``branches_cross``) has an extrapolated branch touching the deciding one at a recorded
    input, a kink of the cost on which Levenberg-Marquardt can stop short of the optimum,
    it is refined again from its branches held apart there while that lowers the cost;
    then each branch that is an extrapolation at some recorded inputs is pushed through
    the other at the median of those inputs and refined again, kept where that is a
    success with a lower cost (the cost is flat in an extrapolation that stays on its own
    side, so no solve sees an optimum where it crosses and decides outputs;
    :mod:`hbjax._identify.refine_kinks`; eager calls only). The returned model is therefore always exactly
    :func:`hbjax.simulate`'s model on the data; ``.extrapolated`` lists the branch ranges
    that are extrapolations, ``.branches_cross`` whether the branches meet at a recorded
    input. Orders are static; record lengths are not: an eager call pads each record to
    its length's bucket and masks the padding out (``docs/performance.md``), so a record of
    a new length costs no new compilation and gives the unpadded record's results.

    The result is not ``successful`` (and ``throw=True`` raises) when the solver failed,
    when ``A`` is unstable (``RESULTS.unstable``, assumption A3), when the input path
    (for the simulation criterion, the free run) predicts the output no better than the
    output's own past (``RESULTS.no_input_effect``), or when the free-run fit on the estimation records
    pooled is below `min_sim_fit` (``RESULTS.poor_fit``, or ``RESULTS.closing_loop`` when
    the branches meet inside the data) and the residual tests do not say the equation
    noise integrated by ``1/A`` explains it (``.noise_limited``, ``.residual_p``;
    ``docs/validation.md``). Parameters the data
    do not identify (rank-deficient Gauss-Newton matrix: a branch that never decides the
    output, a constant input) get ``std = inf`` and are listed in ``.unidentified``.

    **Arguments:**

    - `model`: initial :class:`hbjax.Hammerstein` (e.g. from :func:`hbjax.identify_giri`);
      its orders ``na, nb, m`` are kept. It is first mapped to the chosen normalisation.
    - `recordings`: one ``(v, y)`` pair or a list of pairs (several experiments, any
      input signals, lengths may differ between experiments).
    - `criterion`: ``"prediction"`` or ``"simulation"``.
    - `h_m`: amplitude of the paper's design, selects the normalisation (above).
    - `max_steps`, `rtol`, `atol`: Levenberg–Marquardt limits and tolerances (in the
      scaled free parameters and in residuals divided by the outputs' unit, the power of
      two nearest above their largest magnitude: they mean the same in any unit of ``y``).
    - `min_sim_fit`: floor (%) of the pooled free-run fit on the estimation data
      (default :data:`hbjax._identify.quality.SIM_FIT_FLOOR`, 0 %; below the default, the
      residual tests may accept a fit the noise explains, never below a raised floor).
    - `initial_state`: ``"zero"`` (default: the paper's experiments start at rest) or
      ``"estimate"`` (records that do not start at rest, as MATLAB's
      ``'InitialCondition', 'e'``): the prediction errors of the first ``max(na, nb)``
      samples, whose regressors reach before the record, are left out, and the output
      errors have the response to the unknown output and input lags removed by least
      squares for the current parameters (:mod:`hbjax._identify.stable`); the reported
      free-run fit figures start from the state :func:`hbjax.estimate_initial_state`
      estimates (output lags and play state). Records far from zero (input or output beyond twice
      their half-range from it) are solved less their centres and the result reported
      as recorded, as :func:`hbjax.fit` does (:mod:`hbjax._identify.centring`). The
      criterion's play operator starts at rest at the output's centre; where the records'
      first outputs lie farther from it than 5 % of the output's range, the start is
      refined a second time at rest there and the result whose `sim_fit` is higher is kept
      (a success first; ``centring.at_better_start``). Not under ``jax.jit``.
    - `restarts`: ``k > 0`` (default 16, :data:`AUTO_RESTARTS`): where the result is not
      a success, or (prediction criterion) its one-step errors fail the whiteness or
      independence test of :func:`hbjax.resid` on a record (level 0.01, Bonferroni over
      the records' tests), the records are also fitted from ``k`` random starts
      (:func:`hbjax.fit`, key ``jax.random.PRNGKey(0)``), that optimum is refined in this
      normalisation and kept if it is a success with a lower cost (any success where the
      refinement from `model` failed); eager calls only. ``0`` refines from `model`
      alone (faster where the tests reject anyway). A start far from the optimum (the
      closed form of a high-degree branch, ``m = 5``) can end in a local minimum whose
      errors correlate with the input: on the paper mode's failures of
      ``benchmarks/identify_random.py`` the tests flagged 7 of 9 and 16 starts reached
      the true system's cost in all 9 (``benchmarks/paper_local_minima.py``). On records
      the model structure cannot describe (real data) the tests always reject, so every
      call then also pays for the multi-start fit.
    - `loop_tolerance`: where the branches cross at recorded inputs where both decide
      outputs (a hysteresis loop closing inside the data), the largest free-run fit
      shortfall (%) the estimate's own covariance may predict on the estimation inputs
      for a success; above it the result is ``RESULTS.loop_unresolved`` (``.loop_spread``;
      :mod:`hbjax._identify.loop`). Judged for the prediction criterion where the one-step
      errors pass the residual tests (the covariance then measures the error) and the
      spread is finite. Default ``inf``: refine does not refuse a closing loop (on the
      paper's experiments a refined extrapolation crosses inside the data now and then:
      at 1 % a first version of the rule, without the residual-test and finite-spread
      conditions, refused 35 of 2100 valid paper-mode successes; the final rule would
      still refuse at most one of those 35, not measured on a whole study); pass
      ``loop_tolerance=1.0`` (a 99 % free-run fit, :func:`hbjax.fit`'s default) to judge;
      ``.loop_spread`` is reported either way.
    - `throw`: raise :class:`RefinementError` if the result is not a success (default);
      otherwise inspect ``.result`` / ``.message``.

    **Returns:** a :class:`RefineResult` (``print(result)`` shows the fit, the standard
    errors, unidentified parameters and extrapolated ranges).
    """
    require_x64("refine")
    ensure_compilation_cache()
    check_model(model)
    check_branch_degree(model.backlash.m, "model.backlash.m")
    check_criterion(criterion)
    check_simulation_start(model, criterion)
    recs = as_recordings(recordings, model=model, host=True)
    h_m = check_h_m(h_m)
    max_steps = positive_int(max_steps, "max_steps")
    q = len(param_names(model)) - 1  # (no device work for a count)
    n = total_samples(recs)
    if n <= q:
        raise ValueError(
            f"`recordings` hold {n} samples in all; refining {q} free parameters needs more."
        )
    if not any(is_traced(x) for x in jax.tree_util.tree_leaves(model)):
        check_gauge(model, h_m)
    min_sim_fit = check_floor(min_sim_fit)
    check_initial_state(initial_state)
    check_estimated_start(recs, model.arx.na, model.arx.nb, initial_state)
    throw = check_bool(throw, "throw")
    restarts = positive_int(restarts, "restarts", minimum=0)
    loop_tolerance = check_loop_tolerance(loop_tolerance)
    options = dict(criterion=criterion, h_m=h_m, max_steps=max_steps,
                   rtol=positive_float(rtol, "rtol"), atol=positive_float(atol, "atol"),
                   min_sim_fit=min_sim_fit, initial_state=initial_state)
    # Records far from zero are solved less their centres, as `fit` solves them
    # (centring.py: on an output 64 ranges from zero the criterion's play operator starts
    # beyond both branches, and a refinement from the true system ended 3393 sigma^2 above
    # the optimum, reported as a success); the result is reported as recorded.
    centres = refine_centres(recs, model, initial_state, h_m)
    res = _refine_at(model, recs, centres, options, restarts, loop_tolerance)
    if initial_state == "estimate" and not is_traced(res.result._value) and not any(
            map(is_traced, centres)) and float(jnp.sum(model.arx.b)) != 0.0:
        # as `fit` (a start refined at rest at zero on a record cut from a longer run lost
        # 12 points of validation)
        res = at_better_start(lambda c: _refine_at(model, recs, c, options, restarts,
                                                   loop_tolerance), recs, centres, res)
    if throw and is_traced(res.result._value):
        return raise_if_failed(res)
    # On the host: an eager `!=` of two enumeration items is a device dispatch.
    if throw and int(code(res.result)) != int(code(RESULTS.successful)):
        quality = res.result in (RESULTS.unstable, RESULTS.poor_fit, RESULTS.closing_loop,
                                 RESULTS.branches_cross, RESULTS.no_input_effect,
                                 RESULTS.loop_unresolved)
        raise RefinementError(
            f"refine ({criterion} criterion) "
            f"{'gave an unacceptable model' if quality else 'did not converge'}: {res.message} "
            f"(steps {int(res.stats['steps'])}, mean squared residual "
            f"{float(res.stats['cost']):.4g}); pass throw=False to inspect the result."
        )
    return res
