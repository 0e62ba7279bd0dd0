"""Prediction-error / output-error refinement of an HB-Hammerstein model with optimistix.

``refine`` minimises the sum of squared one-step prediction errors (the maximum-likelihood
criterion under the paper's Gaussian equation error, eq. (10)) or of output errors (free run)
over the normalised parameters, with Levenberg–Marquardt through the differentiable play
operator and ARX recursion. ``refine_traceable`` is its jit/vmap-able core.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float

from .._core import display
from .._core.arx import ARX
from .._core.backlash import Backlash
from .._misc import is_traced, positive_float, positive_int
from .._core.buckets import padded_records, should_bucket
from .._core.cache import ensure_compilation_cache
from .._core.precision import require_x64
from .criteria import (
    PAPER, PREDICTION, STATIC_GAIN, Parametrisation, branches_meet, data_scale,
    lower_is_p1, residuals, sample_count, unpack,
)
from .._core.model import Hammerstein
from .._results import RESULTS, raise_if_failed
from .._core.params import flatten_params, gauge_factor, param_names
from .quality import (
    SIM_FIT_FLOOR, core_consistent, identified, is_stable, mark_unidentified, simulation_fit,
)
from .stable import check_initial_state
from .recordings import as_recordings, check_criterion, check_h_m, check_model, total_samples
from .sufficient import gauss_newton_matrix, solve_by_statistics, worth_it


class RefinementError(ValueError):
    """Raised by :func:`refine` / :func:`fit` (``throw=True``) when the solve failed."""


class RefineResult(eqx.Module):
    """What :func:`refine` found.

    - `model`: the refined :class:`hbjax.Hammerstein`, normalised (see :func:`refine`).
    - `result`: a :class:`RESULTS` code (``RESULTS.successful`` when converged); `message`
      gives it in words.
    - `stats`: ``{"steps", "cost", "initial_cost", "samples"}``: optimiser steps, mean
      squared residual at the optimum and at the start, residuals used.
    - `covariance`: ``sigma^2 (J^T J)^+`` mapped to the normalised parameters (order
      a, b, c1, c2 of :func:`hbjax.flatten_params`); singular along the constraint.
    - `noise_std`: ``sqrt(SSR / (N - q))``, ``q`` the number of free parameters.
    - `branches_cross`: whether the branches cross or meet at some recorded input
      (informational: the model is the core operator ``L = min, H = max`` on the data).
    - `sim_fit`: free-run simulation fit (%) on each estimation record,
      ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)``, simulated from rest as
      :func:`hbjax.simulate` (from the estimated initial state with
      ``initial_state="estimate"``); `sim_fit_pooled` over all records (``RESULTS.poor_fit``
      below :data:`hbjax._identify.quality.SIM_FIT_FLOOR`).
    - `stable`: whether ``A`` has all its poles inside the unit circle (A3;
      ``RESULTS.unstable`` otherwise).
    - `identified`: per parameter (flatten order), whether the data identify it;
      `unidentified` lists the names of those that are not (their `std` is ``inf``).
    - `active_ranges`: ``[[lo, hi] of P1, [lo, hi] of P2]``, the inputs at which each
      branch decides the output (NaN: never); `data_range`: ``[min v, max v]``;
      `extrapolated` says, per branch, where its values are extrapolations the data do not
      constrain directly.
    - `core_finish`: whether the solve was finished on the core operator because the
      labelled band's optimum crossed where the crossing decides the output.
    - `criterion`, `gauge`, `initial_state`: what was minimised, how the gain ambiguity
      was fixed and whether the initial state was estimated.
    """

    model: Hammerstein
    result: RESULTS
    stats: dict
    covariance: Float[Array, "p p"]
    noise_std: Float[Array, ""]
    branches_cross: Bool[Array, ""]
    sim_fit: Float[Array, " records"]
    sim_fit_pooled: Float[Array, ""]
    stable: Bool[Array, ""]
    identified: Bool[Array, " p"]
    active_ranges: Float[Array, "2 2"]
    data_range: Float[Array, " 2"]
    core_finish: Bool[Array, ""]
    criterion: str = eqx.field(static=True)
    gauge: str = eqx.field(static=True)
    initial_state: str = eqx.field(static=True, default="zero")

    @property
    def message(self) -> str:
        """The result code in words, with the numbers it rests on (concrete results)."""
        return describe(self)

    @property
    def std(self) -> Float[Array, " p"]:
        """Standard errors (square roots of the covariance diagonal; ``inf`` for a
        parameter the data do not identify)."""
        return jnp.sqrt(jnp.maximum(jnp.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))

    def summary(self) -> display.Summary:
        """Estimates, standard errors, 95% intervals, unidentified flags, fit figures and the
        result message; a text table that renders as HTML in Jupyter."""
        return display.estimation_summary(self, "Refinement", covariance=self.covariance)

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()

    @property
    def unidentified(self) -> tuple:
        """Names (:func:`hbjax.param_names`) of the parameters the data do not identify."""
        return unidentified_names(self.model, self.identified)

    @property
    def extrapolated(self) -> dict:
        """``{"P1": [(lo, hi), ...], "P2": [...]}``: input ranges inside the data where a
        branch never decides the output (its values there are extrapolations)."""
        return extrapolated_ranges(self.active_ranges, self.data_range)



def gauge_transform(model: Hammerstein, par: Parametrisation):
    """``(A, mu B, P/mu)`` in the gauge of ``par`` and whether ``mu`` was usable.

    Paper gauge: ``mu = P2(-h_m) - P1(h_m)`` (section 4.1); static-gain gauge:
    ``mu = 1 / B(1)``. Traceable: a zero ``mu`` gives ``ok = False``, never NaN.
    """
    bl, arx = model.backlash, model.arx
    if par.gauge == PAPER:
        mu = gauge_factor(bl.c1, bl.c2, par.h_m)
        ok = jnp.isfinite(mu) & (mu != 0)
        inv = 1.0 / jnp.where(ok, mu, 1.0)
        mu = jnp.where(ok, mu, 1.0)
    else:
        gain = jnp.sum(arx.b)
        ok = jnp.isfinite(gain) & (gain != 0)
        inv = jnp.where(ok, gain, 1.0)
        mu = 1.0 / inv
    return Hammerstein(Backlash(bl.c1 * inv, bl.c2 * inv), ARX(arx.a, arx.b * mu)), ok


def make_parametrisation(model, recordings, h_m, lower=True, *, stable=False,
                         initial_state="zero") -> Parametrisation:
    gauge = STATIC_GAIN if h_m is None else PAPER
    h = jnp.asarray(0.0 if h_m is None else h_m, jnp.float64)
    return Parametrisation(model.arx.na, model.arx.nb, model.backlash.m, gauge,
                           data_scale(recordings), h, jnp.asarray(lower), jnp.asarray(False),
                           stable=stable, initial_state=initial_state)


def _flat_residuals(z, par, recordings, criterion):
    return jnp.concatenate(residuals(z, par, recordings, criterion))


def solve(par: Parametrisation, z0, recordings, criterion, *, max_steps, rtol, atol):
    """Levenberg–Marquardt on the free parameters; never raises."""
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, norm=optx.max_norm,
                                     linear_solver=lx.Normal(lx.Cholesky()))

    def fn(z, args):
        return residuals(z, *args, criterion)

    return optx.least_squares(fn, solver, z0, args=(par, recordings), max_steps=max_steps,
                              throw=False)


def _at_optimum(sol, par, recordings, criterion):
    """Residuals and Jacobian at the solution: optimistix keeps both for the last accepted
    point in its state (saves one evaluation); recomputed if that internal layout changes."""
    f_info = getattr(sol.state, "f_info", None)
    if isinstance(f_info, optx.FunctionInfo.ResidualJac):
        return jnp.concatenate(f_info.residual), lx.materialise(f_info.jac).as_matrix()
    z = sol.value
    return (_flat_residuals(z, par, recordings, criterion),
            jax.jacfwd(_flat_residuals)(z, par, recordings, criterion))


def residual_summary(par, z0, r, jac, recordings, criterion):
    """``(SSR, SSR at z0, J^T J)`` of a solver that evaluates the full residual."""
    r0 = _flat_residuals(z0, par, recordings, criterion)
    return jnp.sum(r**2), jnp.sum(r0**2), jac.T @ jac


def summarise(par, z, ssr, ssr0, jtj, n, result, steps, ok):
    """Covariance, noise level, stats and final result code at the optimum ``z``, from the
    sum of squared residuals ``ssr`` (``ssr0`` at the start), ``J^T J`` and the number of
    residuals ``n``.

    ``cov(theta) = D sigma^2 (J^T J)^+ D^T`` with ``J = dr/dz`` and ``D = dtheta/dz``: the
    usual asymptotic covariance of the least-squares estimate, in the normalised
    parameters (the constraint direction has zero variance).
    """
    q = z.shape[0]
    noise_var = ssr / jnp.maximum(n - q, 1)  # n: an int, or traced for padded records
    cov_z = noise_var * jnp.linalg.pinv(jtj, hermitian=True)
    d = par.jacobian()
    cov = d @ cov_z @ d.T
    finite = jnp.all(jnp.isfinite(z)) & jnp.isfinite(ssr)
    result = RESULTS.where(ok, RESULTS.promote(result), RESULTS.gauge_undefined)
    result = RESULTS.where(finite | ~ok, result, RESULTS.nonfinite)
    stats = {"steps": steps, "cost": ssr / n, "initial_cost": ssr0 / n,
             "samples": jnp.asarray(n)}
    return par.model(z), result, stats, cov, jnp.sqrt(noise_var)


def describe(res) -> str:
    """The result code in words; for the quality codes, with the numbers."""
    text = RESULTS[res.result] or "success"
    if res.result == RESULTS.poor_fit or res.result == RESULTS.closing_loop:
        fits = ", ".join(f"{float(f):.1f} %" for f in np.atleast_1d(np.asarray(res.sim_fit)))
        text += (f" (free-run fit {float(res.sim_fit_pooled):.1f} % pooled, per record: "
                 f"{fits}; floor {SIM_FIT_FLOOR:g} %)")
    elif res.result == RESULTS.unstable:
        a = np.asarray(res.model.arx.a)
        radius = float(np.max(np.abs(np.roots(np.concatenate([[1.0], a]))))) if a.size else 0.0
        text += f" (largest pole modulus {radius:.6g})"
    return text


def unidentified_names(model, identified) -> tuple:
    names = param_names(model)
    return tuple(n for n, ok in zip(names, np.asarray(identified)) if not ok)


def extrapolated_ranges(active, data_range) -> dict:
    active, (lo, hi) = np.asarray(active), np.asarray(data_range)
    out = {}
    for k, name in enumerate(("P1", "P2")):
        a, b = active[k]
        if not np.isfinite(a):
            out[name] = [(float(lo), float(hi))]
            continue
        out[name] = [r for r in ((float(lo), float(a)), (float(b), float(hi))) if r[1] > r[0]]
    return out


def _solve_full(par, z0, recordings, criterion, **options):
    """Levenberg–Marquardt on the full residual: ``(z, result, steps, SSR, SSR0, J^T J)``."""
    sol = solve(par, z0, recordings, criterion, **options)
    r, jac = _at_optimum(sol, par, recordings, criterion)
    ssr, ssr0, jtj = residual_summary(par, z0, r, jac, recordings, criterion)
    return sol.value, sol.result, sol.stats["num_steps"], ssr, ssr0, jtj


def _solve_prediction(par, z0, recordings, **options):
    """The prediction criterion by sufficient statistics (:mod:`hbjax._identify.sufficient`),
    finished by the full solve where the play operator's sources did not settle (the step
    count then adds both stages)."""
    z, result, steps, gram, ssr, unsettled, ssr0 = solve_by_statistics(par, z0, recordings,
                                                                       **options)

    def settled_branch(_):
        return z, result, steps, ssr, gauss_newton_matrix(z, par, gram)

    def full_branch(_):
        z_end, res, more, ssr_end, _, jtj = _solve_full(par, z, recordings, PREDICTION,
                                                        **options)
        return z_end, res, steps + more, ssr_end, jtj

    z, result, steps, ssr, jtj = jax.lax.cond(unsettled, full_branch, settled_branch, None)
    return z, result, steps, ssr, ssr0, jtj


def _solve(par, z0, recordings, criterion, statistics, options):
    """One Levenberg–Marquardt solve under ``par``'s band rule:
    ``(z, result, steps, SSR, SSR0, J^T J)``."""
    # (the statistics cover every sample: not with the first ones left out)
    if (criterion == PREDICTION and statistics and par.initial_state == "zero"
            and worth_it(par.na, par.nb, par.m)):
        return _solve_prediction(par, z0, recordings, **options)
    return _solve_full(par, z0, recordings, criterion, **options)


# Touch equalities the labelled solve may add (one per round) before the core finish.
MAX_TOUCHES = 3


def _touch_where_decisive(par, z, result, steps, ssr, jtj, recordings, criterion,
                          statistics, options):
    """Keep the labelled optimum where its branches cross only where no output depends on
    it; otherwise constrain the branches to touch (``P1(x) = P2(x)``) at the input of the
    first sample whose output the crossing changes, and solve again from the projection
    (an active set, up to :data:`MAX_TOUCHES` levels: the constrained optimum, on which
    the labelled and the core operators agree). If the crossing still decides outputs
    then (the data want a closing loop), finish on the core operator from there."""
    ok = optx.RESULTS.successful
    par = eqx.tree_at(lambda p: (p.touch_x, p.touch_on), par,
                      (jnp.zeros(MAX_TOUCHES), jnp.zeros(MAX_TOUCHES, bool)),
                      is_leaf=lambda x: x is None)
    # The start's orientation of the band may be the wrong one (its branches crossed on
    # average over the data): take the optimum's, and solve again if it flips.
    lower = lower_is_p1(par.model(z), recordings)
    flip = (lower != par.lower_is_p1) & (result == ok)
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower)

    def reoriented(_):
        z2, res2, steps2, ssr2, _, jtj2 = _solve(par, z, recordings, criterion, statistics,
                                                 options)
        return z2, res2, steps + steps2, ssr2, jtj2

    z, result, steps, ssr, jtj = jax.lax.cond(flip, reoriented,
                                              lambda _: (z, result, steps, ssr, jtj), None)

    def check(par, z):
        return core_consistent(par.theta_scaled(z), par.band, recordings, par.scale,
                               par.na, par.nb)

    def again(state):
        par, z, result, steps, ssr, jtj, k, consistent, _ = state
        return ~consistent & (result == ok) & (k < MAX_TOUCHES)

    def touch(state):
        par, z, result, steps, ssr, jtj, k, consistent, x_bad = state
        par = eqx.tree_at(lambda p: (p.touch_x, p.touch_on), par,
                          (par.touch_x.at[k].set(x_bad), par.touch_on.at[k].set(True)))
        z2, res2, steps2, ssr2, _, jtj2 = _solve(par, par.feasible(z), recordings, criterion,
                                                 statistics, options)
        consistent, x_bad = check(par, z2)
        return par, z2, res2, steps + steps2, ssr2, jtj2, k + 1, consistent, x_bad

    consistent, x_bad = check(par, z)
    state = (par, z, result, steps, ssr, jtj, jnp.asarray(0), consistent, x_bad)
    par, z, result, steps, ssr, jtj, _, consistent, _ = jax.lax.while_loop(again, touch, state)
    need_core = ~consistent & (result == ok)
    core_par = eqx.tree_at(lambda p: (p.core, p.touch_on), par,
                           (jnp.asarray(True), jnp.zeros(MAX_TOUCHES, bool)))

    def on_core(_):
        z2, res2, steps2, ssr2, _, jtj2 = _solve(core_par, z, recordings, criterion,
                                                 statistics, options)
        return z2, res2, steps + steps2, ssr2, jtj2

    def as_is(_):
        return z, result, steps, ssr, jtj

    z, result, steps, ssr, jtj = jax.lax.cond(need_core, on_core, as_is, None)
    par = eqx.tree_at(lambda p: (p.core, p.touch_on), par,
                      (need_core, par.touch_on & ~need_core))
    # The touches are active inequalities, not knowledge: the covariance is that of the
    # unconstrained parameters at the constrained optimum (a constrained Gauss-Newton
    # matrix would claim the extrapolated branch pinned by the touch).
    free_par = eqx.tree_at(lambda p: p.touch_on, par, jnp.zeros(MAX_TOUCHES, bool))
    z = par.feasible(z)

    def unconstrained(_):
        jac = jax.jacfwd(_flat_residuals)(z, free_par, recordings, criterion)
        return jac.T @ jac

    jtj = jax.lax.cond(jnp.any(par.touch_on), unconstrained, lambda _: jtj, None)
    return free_par, z, result, steps, ssr, jtj


def refine_traceable(model: Hammerstein, recordings, *, criterion: str = "prediction",
                     h_m=None, max_steps: int = 256, rtol: float = 1e-7,
                     atol: float = 1e-7, statistics: bool = True,
                     min_sim_fit: float = SIM_FIT_FLOOR, initial_state: str = "zero",
                     stable: bool = False) -> RefineResult:
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

    ``recordings`` must already be a tuple of ``(v, y)`` float64 array pairs, or of padded
    records ``(v, y, n)`` (zero-padded to a bucket length, ``n`` recorded samples as an
    integer array; :func:`hbjax._identify.criteria.unpack`), which give the unpadded
    records' results from one program per bucket. Works under
    ``jax.jit`` and ``jax.vmap`` (e.g. over noise realisations with the inputs shared);
    see :func:`refine_batch`.
    """
    par = make_parametrisation(model, recordings, h_m, stable=stable,
                               initial_state=initial_state)
    start, ok = gauge_transform(model, par)
    # The band's orientation is taken from the (normalised) start and kept fixed.
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower_is_p1(start, recordings))
    z0 = par.free(flatten_params(start))
    options = dict(max_steps=max_steps, rtol=rtol, atol=atol)
    z, result, steps, ssr, ssr0, jtj = _solve(par, z0, recordings, criterion, statistics,
                                              options)
    par, z, result, steps, ssr, jtj = _touch_where_decisive(par, z, result, steps, ssr, jtj,
                                                            recordings, criterion,
                                                            statistics, options)
    if stable:
        # Back to the affine parameters (a itself) for the covariance and the checks.
        theta = par.theta(z)
        par = dataclasses.replace(par, stable=False)
        z = par.free(theta)
        jac = jax.jacfwd(_flat_residuals)(z, par, recordings, criterion)
        jtj = jac.T @ jac
    n = sample_count(recordings)
    fitted, result, stats, cov, noise_std = summarise(par, z, ssr, ssr0, jtj, n, result,
                                                      steps, ok)
    return finish(fitted, result, stats, cov, noise_std, par, recordings, criterion, jtj,
                  min_sim_fit)


def finish(fitted, result, stats, cov, noise_std, par, recordings, criterion, jtj=None,
           min_sim_fit=SIM_FIT_FLOOR):
    """The result with its quality checks, first failing one wins after the solver's own
    code: ``branches_cross`` (a labelled band whose crossing decides an output; refine's
    core finish never leaves one), ``unstable`` (A3), ``closing_loop`` / ``poor_fit``
    (free-run fit on the estimation data below ``min_sim_fit``; ``closing_loop`` when the
    branches meet inside the data). Parameters the Gauss-Newton matrix ``jtj`` does not
    identify get ``inf`` variance."""
    theta_s = par.free(flatten_params(fitted))
    consistent, _ = core_consistent(par.theta_scaled(theta_s), par.band, recordings, par.scale,
                                 par.na, par.nb)
    fits, pooled, active = simulation_fit(fitted, recordings, par.initial_state)
    stable = is_stable(fitted.arx.a)
    if jtj is None:
        ident = jnp.ones(par.size, bool)
    else:
        ident = identified(jtj, par.jacobian())
        cov = mark_unidentified(cov, ident)
    closing = branches_meet(fitted, recordings)
    good = result == RESULTS.successful
    result = RESULTS.where(good & ~consistent, RESULTS.branches_cross, result)
    good = result == RESULTS.successful
    result = RESULTS.where(good & ~stable, RESULTS.unstable, result)
    good = result == RESULTS.successful
    poor = ~(pooled >= min_sim_fit)
    result = RESULTS.where(good & poor & closing, RESULTS.closing_loop, result)
    result = RESULTS.where(good & poor & ~closing, RESULTS.poor_fit, result)
    v_all = jnp.concatenate([v for v, _, _ in map(unpack, recordings)])
    valid = [mask for _, _, mask in map(unpack, recordings)]
    if any(mask is not None for mask in valid):
        valid = jnp.concatenate([jnp.ones(v.shape[0], bool) if mask is None else mask
                                 for (v, _, _), mask in zip(map(unpack, recordings), valid)])
        data_range = jnp.stack([jnp.min(jnp.where(valid, v_all, jnp.inf)),
                                jnp.max(jnp.where(valid, v_all, -jnp.inf))])
    else:
        data_range = jnp.stack([jnp.min(v_all), jnp.max(v_all)])
    return RefineResult(fitted, result, stats, cov, noise_std, closing, fits, pooled, stable,
                        ident, active, data_range, jnp.asarray(par.core), criterion,
                        par.gauge, par.initial_state)


@eqx.filter_jit
def _refine_jit(model, recordings, criterion, h_m, max_steps, rtol, atol, min_sim_fit,
                initial_state="zero"):
    return refine_traceable(model, recordings, criterion=criterion, h_m=h_m,
                            max_steps=max_steps, rtol=rtol, atol=atol,
                            min_sim_fit=min_sim_fit, initial_state=initial_state)


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
    options as :func:`refine`.

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
    """``min_sim_fit``: a finite real number (percent; may be negative) or a traced value."""
    if is_traced(min_sim_fit):
        return min_sim_fit
    if isinstance(min_sim_fit, bool) or not isinstance(min_sim_fit, (int, float, np.number)) \
            or not np.isfinite(min_sim_fit):
        raise ValueError(f"`min_sim_fit` must be a finite number (percent), got {min_sim_fit!r}.")
    return float(min_sim_fit)


def _check_gauge(model, h_m):
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
    with jax.ensure_compile_time_eval():  # concrete even inside an outer jit
        mu = float(gauge_factor(bl.c1, bl.c2, h_m))
    if mu == 0.0 or not np.isfinite(mu):
        raise ValueError(
            f"mu = P2(-h_m) - P1(h_m) is {mu} for the initial `model` and `h_m` = {h_m}: "
            "the paper's normalisation (section 4.1) cannot be applied; the +-h_m swing "
            "must cross the backlash gap."
        )


def refine(model: Hammerstein, recordings, *, criterion: str = "prediction", h_m=None,
           max_steps: int = 256, rtol: float = 1e-7, atol: float = 1e-7,
           min_sim_fit: float = SIM_FIT_FLOOR, initial_state: str = "zero",
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
    operator from there. The returned model is therefore always exactly
    :func:`hbjax.simulate`'s model on the data; ``.extrapolated`` lists the branch ranges
    that are extrapolations, ``.branches_cross`` whether the branches meet at a recorded
    input. Orders are static; record lengths are not: an eager call pads each record to
    its length's bucket and masks the padding out (``docs/performance.md``), so a record of
    a new length costs no new compilation and gives the unpadded record's results.

    The result is not ``successful`` (and ``throw=True`` raises) when the solver failed,
    when ``A`` is unstable (``RESULTS.unstable``, assumption A3), or when the free-run fit
    on the estimation records pooled is below `min_sim_fit` (``RESULTS.poor_fit``, or
    ``RESULTS.closing_loop`` when the branches meet inside the data). Parameters the data
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
      scaled free parameters and residuals).
    - `min_sim_fit`: floor (%) of the pooled free-run fit on the estimation data
      (default :data:`hbjax._identify.quality.SIM_FIT_FLOOR`, 0 %).
    - `initial_state`: ``"zero"`` (default: the paper's experiments start at rest) or
      ``"estimate"`` (records that do not start at rest, as MATLAB's
      ``'InitialCondition', 'e'``): the prediction errors of the first ``max(na, nb)``
      samples, whose regressors reach before the record, are left out, and the output
      errors have the response to the unknown output and input lags removed by least
      squares for the current parameters (:mod:`hbjax._identify.stable`); the reported
      free-run fit figures start from the state :func:`hbjax.estimate_initial_state`
      estimates (output lags and play state).
    - `throw`: raise :class:`RefinementError` if the result is not a success (default);
      otherwise inspect ``.result`` / ``.message``.

    **Returns:** a :class:`RefineResult` (``print(result)`` shows the fit, the standard
    errors, unidentified parameters and extrapolated ranges).
    """
    require_x64("refine")
    ensure_compilation_cache()
    check_model(model)
    check_criterion(criterion)
    recs = as_recordings(recordings, model=model)
    h_m = check_h_m(h_m)
    max_steps = positive_int(max_steps, "max_steps")
    q = flatten_params(model).shape[0] - 1
    n = total_samples(recs)
    if n <= q:
        raise ValueError(
            f"`recordings` hold {n} samples in all; refining {q} free parameters needs more."
        )
    if not any(is_traced(x) for x in jax.tree_util.tree_leaves(model)):
        _check_gauge(model, h_m)
    min_sim_fit = check_floor(min_sim_fit)
    check_initial_state(initial_state)
    if should_bucket(model, recs, h_m, min_sim_fit):
        # One program per bucket of record lengths; the padding is masked out of every sum.
        recs = padded_records(recs)
    res = _refine_jit(model, recs, criterion, h_m, max_steps, positive_float(rtol, "rtol"),
                      positive_float(atol, "atol"), min_sim_fit, initial_state)
    if throw and is_traced(res.result._value):
        return raise_if_failed(res)
    if throw and res.result != RESULTS.successful:
        quality = res.result in (RESULTS.unstable, RESULTS.poor_fit, RESULTS.closing_loop,
                                 RESULTS.branches_cross)
        raise RefinementError(
            f"refine ({criterion} criterion) "
            f"{'gave an unacceptable model' if quality else 'did not converge'}: {res.message} "
            f"(steps {int(res.stats['steps'])}, mean squared residual "
            f"{float(res.stats['cost']):.4g}); pass throw=False to inspect the result."
        )
    return res
