"""Identification from ordinary data: multi-start refinement in one compiled program.

The cost is non-convex in the backlash parameters (which input samples are inside the band
changes with the band), so ``fit`` draws diverse backlash shapes, solves the linear block for
each by least squares (the regression is linear in ``a, b`` once ``u`` is known: the
separable structure Bai (2002) exploits), and refines the starts one after the other inside
one compiled ``jax.lax.scan``.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._core import display
from .._core.arx import ARX
from .._core.backlash import Backlash
from .._core.buckets import padded_records, should_bucket
from .._core.cache import ensure_compilation_cache
from .._core.mappings import release_compiled_programs
from .._core.progress import check_progress, progress_bar
from .._misc import check_bool, check_key, is_traced, no_spread, positive_int
from .._core.precision import require_x64
from .centring import at_better_start, in_recorded_coordinates, less_centres, record_centres
from .criteria import PREDICTION, SIMULATION, data_scale
from .fit_criterion import (
    AUTO, choose_criterion, search_after_failure, worth_output_error_search,
)
from .fit_gauge import better_in_paper_gauge, gain_vanishes
from .fit_starts import (
    arx_given_backlash, canonical_labels, canonical_result, closing_band, closing_count,
    closing_positions, random_backlash,
)
from .._core.model import Hammerstein
from .._core.params import flatten_params
from .recordings import as_recordings, check_branch_degree, check_criterion, total_samples
from .quality import SIM_FIT_FLOOR
from .stable import check_estimated_start, check_initial_state
from .._results import RESULTS, code as result_code, raise_if_failed
from .refine import check_floor, refine, refine_traceable
from .loop import LOOP_TOLERANCE, check_loop_tolerance, judge_loop
from .free_run import judge_free_run
from .undetermined import judge_branches, refuse_unseen
from .refine_result import AbstractRefinement, RefinementError, at_estimated_start


class FitResult(AbstractRefinement):
    """What :func:`fit` found.

    - `model`: the best local optimum (lowest cost among converged starts), in the
      static-gain normalisation ``B(1) = 1`` with ``P1`` the branch a rising input drives
      the output onto (see :func:`fit`).
    - `result`, `message`: result code of that start (:class:`hbjax.RESULTS`);
      only stable models with a significant input path whose free-run fit clears the
      floor (or whose residual tests say the noise explains it, see :func:`hbjax.refine`)
      are successes, so the best start is chosen among those (``RESULTS.unstable`` /
      ``no_input_effect`` / ``poor_fit`` when none is). The best start is then judged:
      ``RESULTS.loop_unresolved`` where its loop closes inside the data unpinned,
      ``RESULTS.branches_undetermined`` where the records do not determine its branches,
      ``RESULTS.branches_between_levels`` where they determine them only at the recorded
      inputs.
    - `interpolation_ratio`: the larger over the two branches of a branch's largest
      standard deviation between the recorded inputs (inside the range where it decides
      the output) over its largest at them; 1 for an input that moves through its range,
      above 2 (``RESULTS.branches_between_levels``) where the branches are known only at
      the recorded levels; NaN where a parameter is unidentified. (Where `fit` took a far
      output offset out, :mod:`hbjax._identify.centring`, it is the centred solve's.)
    - `free_run_spread`: where the best start succeeded (eager calls), the free-run
      standard deviation its covariance implies on the estimation records, pooled, in
      percent of the simulated output's spread (``RESULTS.free_run_undetermined`` above
      ``100 - min_sim_fit``: :mod:`hbjax._identify.free_run`); ``None`` otherwise.
    - `stats`, `covariance`, `noise_std`, `branches_cross`, `sim_fit`, `sim_fit_pooled`,
      `stable`, `identified` (and `unidentified`), `active_ranges`, `data_range` (and
      `extrapolated`), `core_finish`, `residual_p` (and `noise_limited`), `loop_spread`,
      `loop_tolerance`: as :class:`RefineResult`, for the chosen start.
    - `starts_costs`: mean squared residual reached from every start, shape ``(starts,)``
      (``inf`` where a start failed).
    - `starts_params`: the local optima, shape ``(starts, p)`` (flatten order).
    - `starts_result`: integer result code of every start.
    - `spread`: standard deviation of the converged local optima per parameter.
    - `hit_rate`: fraction of starts that reached the best cost (relative 1e-6); the
      closing starts (the last quarter) count too, and on data whose loop stays open they
      often end elsewhere (0.78 on a staircase record of the default system, 32 starts).
    - `best_index`: which start won.
    - `criterion`: the criterion of the reported model; `criterion_choice`: with the
      default ``criterion="auto"``, how it was chosen (:mod:`hbjax._identify.fit_criterion`;
      where the prediction fit did not succeed, whether the output-error criterion's own
      search ran and succeeded; empty under ``jax.jit``); with
      ``criterion="prediction"`` asked for, a note where the one-step errors are coloured
      (the criterion's noise assumption fails), else empty.
      `prediction_whiteness_p`: the Ljung-Box p-value of the prediction optimum's
      one-step errors the choice was made on (NaN where not tested; ``None`` where not
      computed). Where the output-error refinement was adopted, `model`, `result`,
      `stats` (its `initial_cost` is the output-error cost at the prediction optimum) and
      the covariance fields are the refinement's, while the starts' fields
      (`starts_costs` ... `best_index`, `spread`, `hit_rate`) describe the prediction
      criterion's starts it began from.
    """

    starts_costs: Float[Array, " starts"]
    starts_params: Float[Array, "starts p"]
    starts_result: Int[Array, " starts"]
    spread: Float[Array, " p"]
    hit_rate: Float[Array, ""]
    best_index: Int[Array, ""]

    criterion: str = eqx.field(static=True, default="prediction")
    gauge: str = eqx.field(static=True, default="static_gain")
    initial_state: str = eqx.field(static=True, default="zero")
    criterion_choice: str = eqx.field(static=True, default="")
    # set by fit_criterion.choose_criterion on an eager prediction-criterion success
    prediction_whiteness_p: Float[Array, ""] | None = None
    # set by the final judgement (undetermined.judge_branches), which every fit runs
    interpolation_ratio: Float[Array, ""] | None = None
    # set by free_run.judge_free_run on an eager fit's success
    free_run_spread: Float[Array, ""] | None = None

    def summary(self) -> display.Summary:
        """Estimates, standard errors, 95% intervals, the spread of the local optima over
        the starts, unidentified flags, fit figures and the result message."""
        return display.estimation_summary(self, "Multi-start identification",
                                          covariance=self.covariance,
                                          extra={"start spread": self.spread})


def _chosen(r, recordings, na: int, nb: int, m: int) -> dict:
    """The fields of one start's :class:`RefineResult` as :class:`FitResult` reports them,
    with labels made canonical (:func:`canonical_result`, in every gauge)."""
    r = canonical_result(r, recordings)
    return dict(
        model=r.model, result=r.result, stats=r.stats, covariance=r.covariance,
        noise_std=r.noise_std, branches_cross=r.branches_cross, sim_fit=r.sim_fit,
        sim_fit_pooled=r.sim_fit_pooled, stable=r.stable, identified=r.identified,
        active_ranges=r.active_ranges, data_range=r.data_range, core_finish=r.core_finish,
        residual_p=r.residual_p, min_sim_fit=r.min_sim_fit, loop_spread=r.loop_spread,
        loop_tolerance=r.loop_tolerance)


def _starts_summary(ok, costs, params, best):
    """``(spread, hit_rate)`` of the starts: the standard deviation of the converged local
    optima per parameter, and the fraction of starts that reached the best cost."""
    n_ok = jnp.maximum(jnp.sum(ok), 1)
    mean = jnp.sum(jnp.where(ok[:, None], params, 0.0), axis=0) / n_ok
    spread = jnp.sqrt(jnp.sum(jnp.where(ok[:, None], (params - mean) ** 2, 0.0), axis=0) / n_ok)
    hits = ok & (costs <= costs[best] * (1 + 1e-6))
    return spread, jnp.sum(hits) / ok.shape[0]


def polish_best(res: "FitResult", recordings, *, criterion, max_steps, min_sim_fit,
                initial_state, rtol: float = 1e-7, atol: float = 1e-7) -> "FitResult":
    """The starts solve on the labelled band (or, the closing ones, the core operator) only;
    the best one is refined once more as `refine` does, with the core operator's solve as
    well. Where the branches meet or cross inside the data, the labelled band cannot follow
    the loop and the best start can be a local minimum the core solve leaves (measured on
    random closing-loop systems: 210-1600 sigma^2 above the true system's cost -> at it).
    The refined start replaces the best one where it succeeds with a lower cost (or none
    had succeeded). Traceable; :func:`fit` compiles it on its own, and runs it only where
    it can change the result."""
    return polished_best(res, recordings, criterion=criterion, max_steps=max_steps,
                         min_sim_fit=min_sim_fit, initial_state=initial_state, rtol=rtol,
                         atol=atol)[0]


def polished_best(res: "FitResult", recordings, *, criterion, max_steps, min_sim_fit,
                  initial_state, rtol=1e-7, atol=1e-7, margin=-1e-9):
    """``(result, taken)``: :func:`polish_best`'s result and whether the refined start
    replaced the best one (a success whose cost is below ``(1 + margin)`` times the best
    start's, or any success where none had succeeded). The refinement is in the
    static-gain gauge ``B(1) = 1`` whatever the gauge of `res`."""
    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    best = res.best_index
    polished = refine_traceable(res.model, recordings, criterion=criterion, h_m=None,
                                max_steps=max_steps, rtol=rtol, atol=atol, statistics=False,
                                min_sim_fit=min_sim_fit, initial_state=initial_state,
                                stable=True, core_start=True)
    ok = res.starts_result == result_code(RESULTS.successful)
    take = (polished.result == RESULTS.successful) & (
        ~ok[best] | (polished.stats["cost"] < res.starts_costs[best] * (1 + margin)))
    new = _chosen(polished, recordings, na, nb, m)
    old = {k: getattr(res, k) for k in new}
    fields = jax.tree_util.tree_map(lambda a, b: jnp.where(take, a, b), new, old)
    ok = ok.at[best].set(ok[best] | take)
    costs = res.starts_costs.at[best].set(
        jnp.where(take, polished.stats["cost"], res.starts_costs[best]))
    params = res.starts_params.at[best].set(flatten_params(fields["model"]))
    codes = res.starts_result.at[best].set(result_code(fields["result"]))
    spread, hit_rate = _starts_summary(ok, costs, params, best)
    return dataclasses.replace(res, **fields, starts_costs=costs, starts_params=params,
                               starts_result=codes, spread=spread, hit_rate=hit_rate), take


def _score(res):
    """A start's rank (lower is better): its cost if it succeeded, else a large constant if
    it ended finite (a failed start still beats none), else ``inf``."""
    cost = res.stats["cost"]
    return jnp.where(res.result == RESULTS.successful, cost,
                     jnp.where(jnp.isfinite(cost), 1e300, jnp.inf))


#: Failures of a start whose solve converged and whose model was then judged: what they
#: say is about the records (no input effect, below the floor ...), not about the solver.
_JUDGED = (RESULTS.branches_cross, RESULTS.unstable, RESULTS.poor_fit, RESULTS.closing_loop,
           RESULTS.no_input_effect)


def _best_start(res):
    """``(ok, costs, best)``: which starts succeeded, their costs (``inf`` where not) and
    the best one. If none succeeded, the least bad, reported with its failure code: the
    lowest cost among the starts whose solve converged and was judged (:data:`_JUDGED`),
    else among those with a finite cost. (An output unrelated to the input, fitted with
    the simulation criterion, ended with its lowest cost at a singular linear solve while
    the other starts said "no input effect": the solver's text was reported.)"""
    ok = res.result == RESULTS.successful
    costs = jnp.where(ok, res.stats["cost"], jnp.inf)
    finite = jnp.where(jnp.isfinite(res.stats["cost"]), res.stats["cost"], jnp.inf)
    judged = jnp.zeros_like(ok)
    for item in _JUDGED:
        judged = judged | (res.result == item)
    least_bad = jnp.where(jnp.any(judged & jnp.isfinite(finite)),
                          jnp.argmin(jnp.where(judged, finite, jnp.inf)), jnp.argmin(finite))
    best = jnp.where(jnp.any(ok), jnp.argmin(costs), least_bad)
    return ok, costs, best


def fit_traceable(recordings, key, *, na: int, nb: int, m: int, starts: int = 32,
                  criterion: str = "prediction", max_steps: int = 256,
                  rtol: float = 1e-7, atol: float = 1e-7,
                  min_sim_fit: float = SIM_FIT_FLOOR,
                  initial_state: str = "estimate", polish: bool = True,
                  level: float | None = None) -> FitResult:
    """Traceable core of :func:`fit` (recordings a tuple of ``(v, y)`` arrays).

    ``level=None`` solves every start in the static-gain gauge ``B(1) = 1``; a number
    solves them in the paper's gauge ``P2(-h) - P1(h) = 1`` at ``h = level max|v|``
    instead (:mod:`hbjax._identify.fit_gauge`: where the data put ``B(1)`` near 0), the
    local optima in `starts_params` still in ``B(1) = 1``.

    ``polish=False`` leaves out the best start's refinement with the core operator's solve
    (:func:`polish_best`), which changes nothing unless the best start's branches meet
    inside the data or no start succeeded: :func:`fit` runs without it and applies
    :func:`polish_best`, compiled on its own, only then (and not where the best start is a
    closing start, already solved on the core operator)."""
    scale = data_scale(recordings)
    keys = jax.random.split(key, starts)
    skip = max(na, nb) if initial_state == "estimate" else 0
    n_close = closing_count(starts, m)

    h_m = None if level is None else level * scale

    def refined(init, core_only):
        return refine_traceable(
            init, recordings, criterion=criterion, h_m=h_m, max_steps=max_steps,
            rtol=rtol, atol=atol, statistics=False, min_sim_fit=min_sim_fit,
            initial_state=initial_state, stable=True, core_start=False,
            core_only=core_only)

    n_open = starts - n_close
    positions = jnp.asarray(np.concatenate([np.zeros(n_open), closing_positions(n_close)]))

    def one(best, args):
        # The last n_close starts close the best open start's loop inside the data
        # (closing_band) and are solved on the core operator: where the true loop closes
        # inside the data, every start from an open band (and a refinement of the best of
        # them) ended in one local minimum on some systems (a crossing system: 380 sigma^2
        # above the optimum from all 32 starts), because the labelled band reopens the loop.
        # One compiled refinement serves both kinds (the operator is a runtime choice).
        best_model, best_score = best
        k, x0, i = args
        closing = i >= n_open
        bl = random_backlash(k, m, scale)
        if n_close:
            bl = jax.tree_util.tree_map(lambda a, b: jnp.where(closing, a, b),
                                        closing_band(best_model, scale, x0), bl)
        init = Hammerstein(bl, arx_given_backlash(bl, recordings, na, nb, skip))
        r = refined(init, core_only=closing if n_close else False)
        score = _score(r)
        better = ~closing & (score < best_score)
        best = jax.tree_util.tree_map(lambda a, b: jnp.where(better, a, b),
                                      (r.model, score), best)
        return best, r

    # A sequential scan, not vmap: under vmap every lax.cond of the refinement (reorientation,
    # touches, core finish) runs both branches and every while loop runs until the slowest
    # start stops, about 10x the work on the tanks (20 s against 1.9 s of CPU, 32 starts);
    # each start's results are the same.
    empty = Hammerstein(Backlash(jnp.zeros(m), jnp.zeros(m)), ARX(jnp.zeros(na), jnp.zeros(nb)))
    _, res = jax.lax.scan(one, (empty, jnp.asarray(jnp.inf)),
                          (keys, positions, jnp.arange(starts)))

    ok, costs, best = _best_start(res)
    # (the optima of the paper's gauge listed in B(1) = 1, as the result is reported)
    form = (lambda mdl: mdl) if level is None else static_gain_form
    params = jax.vmap(lambda mdl: flatten_params(canonical_labels(form(mdl), recordings)[0]))(
        res.model)
    spread, hit_rate = _starts_summary(ok, costs, params, best)
    out = FitResult(
        **_chosen(jax.tree_util.tree_map(lambda x: x[best], res), recordings, na, nb, m),
        starts_costs=costs, starts_params=params, starts_result=result_code(res.result),
        spread=spread, hit_rate=hit_rate, best_index=best, criterion=criterion,
        gauge="static_gain" if level is None else "paper", initial_state=initial_state)
    if polish:
        out = polish_best(out, recordings, criterion=criterion, max_steps=max_steps,
                          rtol=rtol, atol=atol, min_sim_fit=min_sim_fit,
                          initial_state=initial_state)
    return out


_fit_jit = eqx.filter_jit(fit_traceable)
_polish_jit = eqx.filter_jit(polish_best)
_polished_jit = eqx.filter_jit(polished_best)


def _solve(recs, key, centres, traced, loop_tolerance, options):
    """The starts, the polish and the judgements of :func:`fit` on the records less
    `centres`, reported on the records as recorded."""
    moved = any(is_traced(c) or float(c) != 0.0 for c in centres)
    solved = less_centres(recs, *centres) if moved else recs
    starts, m, criterion = options["starts"], options["m"], options["criterion"]
    # One program per bucket of record lengths, as refine's (the padding is masked out of
    # every sum): the starts' program took 10-25 s to compile for each new length.
    bucketed = not traced and should_bucket(solved)
    padded = padded_records(solved) if bucketed else solved
    res = _fit_jit(padded, key, polish=traced, **options)
    # A closing start was solved on the core operator already (under jit, fit_traceable
    # polished the best start itself).
    if not traced and (
            (bool(res.branches_cross)
             and not int(res.best_index) >= starts - closing_count(starts, m))
            or res.result != RESULTS.successful):
        # Only a loop closing inside the data (or no success) needs the core solve of
        # the best start: compiled on its own, from the starts' result.
        res = _polish_jit(res, padded, criterion=criterion, max_steps=options["max_steps"],
                          min_sim_fit=options["min_sim_fit"],
                          initial_state=options["initial_state"])
    if not traced and gain_vanishes(res.model):
        res = better_in_paper_gauge(res, padded, key, _fit_jit, _polished_jit, options)
    if bucketed and options["initial_state"] == "estimate":
        # (the padded solve's figure fits only the output lags of the start, as refine's)
        res = at_estimated_start(res, solved)
    res = judge_branches(judge_loop(res, solved, loop_tolerance), solved)
    if not traced:
        res = judge_free_run(res, solved)
    if moved:
        # (judged on the centred records; a constant term that draws on an
        # unidentified a or b is unidentified on the records as recorded)
        res = refuse_unseen(in_recorded_coordinates(res, *centres, _starts_summary))
    return res


def fit(recordings, *, na: int, nb: int, m: int, key, starts: int = 32,
        criterion: str = AUTO, max_steps: int = 256,
        min_sim_fit: float = SIM_FIT_FLOOR, initial_state: str = "estimate",
        loop_tolerance: float = LOOP_TOLERANCE, throw: bool = True,
        progress=True) -> FitResult:
    """Identify an HB-Hammerstein model from ordinary recordings (steps, multisines, random
    levels; no special input), by multi-start nonlinear least squares.

    Each start draws a random band (:func:`random_backlash`: half-gap log-uniform over
    two decades of the input range, random offset and curvature), takes the linear block
    by least squares given that band, and is refined by :func:`hbjax.refine`'s
    Levenberg–Marquardt; the ``starts`` refinements run one after the other inside one
    compiled program (``jax.lax.scan``: on a CPU each start stops at its own convergence and
    takes only its own branches, which ``vmap`` would not). The last quarter of the starts
    (:func:`closing_count`) instead close the best open start's loop inside the data
    (:func:`closing_band`) and are solved on the core operator ``L = min, H = max``: where
    the true branches meet or cross inside the data, the labelled band of the open starts
    reopens the loop and every one of them can end in the same local minimum. The best
    converged local optimum is returned with the spread of all of them.

    Every start searches within the stable linear blocks only (assumption A3): ``A`` is
    parametrised by its reflection coefficients ``k_i = tanh(zeta_i)`` (Levinson step-up,
    :mod:`hbjax._identify.stable`), so the search cannot leave the stable models and an
    unstable least-squares start is projected onto them. Where the data would prefer an
    unstable ``A`` (a drift, an integrator) the optimum lies at the stability boundary
    (a pole close to 1) instead. A start succeeds only if it converged, its linear block is
    stable and its free-run fit on the estimation data clears `min_sim_fit`; the best such
    start is returned.

    Normalisation (no ``h_m`` is needed): ``B(1) = b_1 + ... + b_nb = 1`` (all the static
    gain in the backlash, assumption A5), and ``P1`` is the branch a rising input drives
    the output onto (:func:`canonical_labels`). Where the best optimum has almost no static
    gain (``|B(1)| < 0.05 sum |b|``), that normalisation is badly scaled for the search and
    the starts are solved a second time in the paper's gauge, the better optimum then
    reported in ``B(1) = 1`` (:mod:`hbjax._identify.fit_gauge`; ``hit_rate`` and the
    starts' fields then describe that pass). Compare with a true model through
    :func:`hbjax.normalise_static_gain`; map to the paper's normalisation with
    :func:`hbjax.normalise` when ``h_m`` is known.

    **Arguments:**

    - `recordings`: one ``(v, y)`` pair or a list of pairs.
    - `na`, `nb`, `m`: orders of ``A``, ``B`` and the number of coefficients per branch.
    - `key`: a JAX PRNG key (the starts).
    - `starts`: number of starts.
    - `criterion`: ``"auto"`` (default), ``"prediction"`` (equation error) or
      ``"simulation"`` (output error). ``"auto"`` fits with the prediction criterion and
      keeps that result where its one-step errors pass the whiteness test (p >= 1e-3,
      the equation-error model of eq. (10) holds); where they are coloured (noise at the
      sensor, or dynamics the model lacks) it refines the optimum with the simulation
      criterion, consistent under either noise, searches the starts with it too, and
      reports the lower-cost of the two where it succeeds; where they are white, it does so
      where that refinement's own free-run errors are white and its one-step errors
      coloured (sensor noise, whose bias can whiten the prediction optimum's errors).
      Where no prediction start succeeds (for another reason than inputs that do not
      determine the branches), the starts are searched again with the simulation
      criterion, whose success is reported where the noise is not the equation's by
      those readings (`criterion_choice` says which and why;
      :mod:`hbjax._identify.fit_criterion`).
      Under ``jax.jit`` ``"auto"`` is the prediction criterion.
    - `max_steps`: Levenberg–Marquardt steps per start.
    - `min_sim_fit`: floor (%) of the pooled free-run fit on the estimation data below
      which a start is not a success (``RESULTS.poor_fit``; default 0 %).
    - `initial_state`: ``"estimate"`` (default: real records rarely start at rest) or
      ``"zero"`` (the paper's convention); see :func:`hbjax.refine`. With ``"estimate"``
      the criterion leaves the unknown past out and `sim_fit` starts from the initial
      state :func:`hbjax.estimate_initial_state` finds. The criterion's play operator
      starts at rest at the output's centre (zero for records near zero); where the
      records' first outputs lie farther from it than 5 % of the output's range, the
      starts are solved a second time at rest there, and the result whose `sim_fit` is
      higher is kept (a success first; of two failures, the first). Not under ``jax.jit``.
    - `loop_tolerance`: as in :func:`hbjax.refine` (default here 1 %): the best start,
      where its loop closes inside the data, is a success only if its own covariance
      predicts a free-run fit shortfall of at most this many percent
      (``RESULTS.loop_unresolved`` otherwise; the starts are chosen before this
      judgement, so it never trades the optimum for a worse start); ``inf`` accepts any
      closing loop.
    - `throw`: raise :class:`hbjax.RefinementError` if no start succeeded, or the best
      one's loop is not pinned (``RESULTS.loop_unresolved``), or the records do not
      determine its branches (``RESULTS.branches_undetermined``: a branch coefficient
      unidentified; ``RESULTS.branches_between_levels``: known only at the recorded
      inputs; :mod:`hbjax._identify.undetermined`).
    - `progress`: a progress bar (``tqdm.auto``, on stderr) once the fit has run for more
      than 2 s on a terminal or in Jupyter; ``False`` silences it, a dict passes options
      to tqdm (``docs/performance.md``).

    **Returns:** a :class:`FitResult`.
    """
    release_compiled_programs()  # (here: its warning names the caller's line)
    return fit_unnoted(recordings, na=na, nb=nb, m=m, key=key, starts=starts,
                       criterion=criterion, max_steps=max_steps, min_sim_fit=min_sim_fit,
                       initial_state=initial_state, loop_tolerance=loop_tolerance,
                       throw=throw, progress=progress, note=True)


def fit_unnoted(recordings, *, na, nb, m, key, starts=32, criterion=AUTO, max_steps=256,
                min_sim_fit=SIM_FIT_FLOOR, initial_state="estimate",
                loop_tolerance=LOOP_TOLERANCE, throw=True, progress=True,
                note=False) -> FitResult:
    """:func:`fit`, for the package's own multi-start searches (:func:`hbjax.refine`'s
    restarts, :func:`hbjax.select_structure`'s rows): with ``note=False`` an explicit
    prediction criterion skips the whiteness test whose only use is `criterion_choice`'s
    note, which those callers never show (it costs a compilation on a first call, 4 s,
    and 0.2 s warm); ``"auto"`` still runs it, since it chooses the criterion."""
    require_x64("fit")
    ensure_compilation_cache()
    release_compiled_programs()
    check_progress(progress)
    throw = check_bool(throw, "throw")
    na = positive_int(na, "na", minimum=0)
    nb = positive_int(nb, "nb")
    m = check_branch_degree(m)
    starts = positive_int(starts, "starts")
    max_steps = positive_int(max_steps, "max_steps")
    auto = check_criterion(criterion, also=(AUTO,)) == AUTO
    check_initial_state(initial_state)
    check_key(key)
    loop_tolerance = check_loop_tolerance(loop_tolerance)
    recs = as_recordings(recordings)
    check_estimated_start(recs, na, nb, initial_state)
    q = na + nb + 2 * m - 1
    if total_samples(recs) <= 2 * q:
        raise ValueError(
            f"`recordings` hold {total_samples(recs)} samples; fitting {q} free parameters "
            f"needs more than {2 * q}."
        )
    if not any(is_traced(y) for _, y in recs) and all(
            no_spread(np.asarray(y)) for _, y in recs):
        # every start's least squares gives B = 0, refused for its gauge: say why instead
        raise ValueError(
            "`recordings`: the output y is constant in every record, so there is no "
            "response to identify a model from (check that y is the output channel and "
            "that the sensor was connected).")
    # Records far from zero are solved less their centres (centring.py: the powers of v
    # are nearly collinear there, and an output offset swamps the output's unit); the
    # result is reported in the records' own coordinates.
    options = dict(na=na, nb=nb, m=m, starts=starts,
                   criterion=PREDICTION if auto else criterion,
                   max_steps=max_steps, min_sim_fit=check_floor(min_sim_fit),
                   initial_state=initial_state)
    traced = any(is_traced(x) for x in jax.tree_util.tree_leaves((recs, key)))
    centres = record_centres(recs, initial_state)
    # The starts run inside one compiled program: the bar shows the elapsed time.

    def search(options):
        res = _solve(recs, key, centres, traced, loop_tolerance, options)
        if initial_state == "estimate" and not traced:
            res = at_better_start(lambda c: _solve(recs, key, c, traced, loop_tolerance,
                                                   options), recs, centres, res)
        return res

    with progress_bar(progress, total=starts, desc="fit", unit="start", live=True) as bar:
        res = search(options)
        if auto and not traced and worth_output_error_search(res):
            res = search_after_failure(
                res, recs, initial_state=initial_state,
                search_output_error=lambda: search(dict(options, criterion=SIMULATION)))
        if options["criterion"] == PREDICTION and not traced and (auto or note):
            res = choose_criterion(res, recs, initial_state=initial_state, auto=auto,
                                   refine_output_error=lambda model: refine(
                model, recs, criterion=SIMULATION, max_steps=max_steps,
                min_sim_fit=options["min_sim_fit"], initial_state=initial_state,
                restarts=0, throw=False), adopt=lambda res, refined: _adopt(
                    res, refined, recs, loop_tolerance),
                search_output_error=lambda: search(dict(options, criterion=SIMULATION)))
        jax.block_until_ready(res)
        bar.update(starts)
    if throw and is_traced(res.result._value):
        return raise_if_failed(res)
    if throw and (res.result == RESULTS.loop_unresolved
                  or res.result == RESULTS.free_run_undetermined
                  or res.result == RESULTS.branches_undetermined
                  or res.result == RESULTS.branches_between_levels):
        raise RefinementError(f"fit: the best start succeeded, but {res.message}.")
    if throw and res.result != RESULTS.successful:
        if all(no_spread(np.asarray(v)) for v, _ in recs):
            # the generic advice (slow poles, other starts) does not apply: nothing moved
            raise RefinementError(
                f"fit: no start succeeded; the best: {res.message.rstrip('.')}. Here the "
                "input `v` is constant in every record, so the records cannot show an effect "
                "of it (the branches are not identified: see .unidentified with "
                "throw=False); record an input that moves."
            )
        raise RefinementError(
            f"fit: no start succeeded; the best: {res.message.rstrip('.')}. Try more "
            "`starts` or `max_steps`, other orders"
            + (", or criterion='simulation'." if criterion == PREDICTION else ".")
        )
    return res


def _adopt(res: FitResult, refined, recordings, loop_tolerance) -> FitResult:
    """`res` with the chosen start's fields replaced by the output-error refinement
    `refined` (a :class:`RefineResult` on the same records), judged as :func:`fit` judges
    its best start."""
    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    out = dataclasses.replace(res, **_chosen(refined, recordings, na, nb, m),
                              criterion=SIMULATION, interpolation_ratio=None,
                              free_run_spread=None)
    return judge_free_run(judge_branches(judge_loop(out, recordings, loop_tolerance),
                                         recordings), recordings)


def normalise_static_gain(model: Hammerstein) -> Hammerstein:
    """The model in the static-gain normalisation of :func:`fit` / :func:`refine` without
    ``h_m``: ``(A, B / B(1), P * B(1))`` so that ``B(1) = 1`` (same input-output
    behaviour, ``u0 = 0``)."""
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    gain = jnp.sum(model.arx.b)
    if not is_traced(gain) and float(gain) == 0.0:
        raise ValueError("`model` has B(1) = sum(b) = 0: the static-gain normalisation "
                         "cannot be applied (assumption A5).")
    return static_gain_form(model)


def static_gain_form(model: Hammerstein) -> Hammerstein:
    """``(A, B / B(1), P * B(1))`` without checks (traceable; ``B(1) = 0`` gives inf)."""
    gain = jnp.sum(model.arx.b)
    bl = model.backlash
    return Hammerstein(Backlash(bl.c1 * gain, bl.c2 * gain), ARX(model.arx.a, model.arx.b / gain))
