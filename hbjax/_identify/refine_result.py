"""The result of a refinement and its assembly: covariance and statistics at the optimum,
the quality checks that decide the final result code, and the result code in words.

:func:`hbjax.refine` and :func:`hbjax.fit` report through these; separable least squares
assembles its result with the same :func:`summarise` and :func:`finish`.
"""

import abc
import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._core import display
from .._core.buckets import padded_records
from .._core.model import Hammerstein
from .._core.params import flatten_params, param_names
from .._results import RESULTS
from .adequacy import (
    LEVEL, input_effect_p, noise_explains, simulated_input_effect_p, whiteness_p,
)
from .criteria import PREDICTION, branches_meet, unpack
from .quality import (
    SIM_FIT_FLOOR, core_consistent, gauss_newton_inverse, identified, is_stable,
    mark_unidentified, simulation_fit,
)
from .uncertainty import free_run_std


class RefinementError(ValueError):
    """Raised by :func:`refine` / :func:`fit` (``throw=True``) when the solve failed."""


class AbstractRefinement(eqx.Module):
    """The fields and reading of a refined model that :class:`RefineResult` and
    :class:`hbjax.FitResult` share (see :class:`RefineResult` for their meaning): one home,
    so that a figure added to refinement reaches multi-start fitting too. Subclasses add
    their own fields and ``summary()``."""

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
    residual_p: Float[Array, " 3"]
    min_sim_fit: Float[Array, ""]
    loop_spread: Float[Array, ""]
    loop_tolerance: Float[Array, ""]

    @property
    def input_effect_p(self) -> Float[Array, ""]:
        """p-value of *no input effect* (``residual_p[2]``): at or above 0.01 the result is
        ``RESULTS.no_input_effect``."""
        return self.residual_p[..., 2]

    @property
    def whiteness_p(self) -> Float[Array, " 2"]:
        """p-values of the one-step errors' whiteness and independence from past inputs
        (``residual_p[:2]``; NaN unless the free-run fit is below the floor)."""
        return self.residual_p[..., :2]

    @property
    def noise_limited(self) -> Bool[Array, ""]:
        """Whether the free-run fit is below the floor only because the equation noise,
        integrated by ``1/A``, dominates the output (:mod:`hbjax._identify.adequacy`): the
        residual tests in `residual_p` pass, so the result may still be a success."""
        return (~(self.sim_fit_pooled >= self.min_sim_fit) & (self.min_sim_fit <= SIM_FIT_FLOOR)
                & noise_explains(self.residual_p))

    @property
    def message(self) -> str:
        """The result code in words, with the numbers it rests on (concrete results)."""
        return describe(self)

    @property
    def std(self) -> Float[Array, " p"]:
        """Standard errors (square roots of the covariance diagonal; ``inf`` for a
        parameter the data do not identify)."""
        return jnp.sqrt(jnp.maximum(jnp.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))

    @property
    def unidentified(self) -> tuple:
        """Names (:func:`hbjax.param_names`) of the parameters the data do not identify."""
        return unidentified_names(self.model, self.identified)

    def free_run_std(self, v, *, u0=0.0, y0=None) -> Float[Array, " time"]:
        """Standard deviation, sample by sample, of the free run
        ``hbjax.simulate(self.model, v, u0=u0, y0=y0)`` that this estimate's covariance
        implies (first-order propagation; ``inf`` where an unidentified parameter moves the
        output): how far a validation record's free run may honestly differ from it through
        the estimation error alone (`docs/validation.md`)."""
        return free_run_std(self.model, self.covariance, v, u0=u0, y0=y0)

    @property
    def extrapolated(self) -> dict:
        """``{"P1": [(lo, hi), ...], "P2": [...]}``: input ranges inside the data where a
        branch never decides the output (its values there are extrapolations)."""
        return extrapolated_ranges(self.active_ranges, self.data_range)

    @abc.abstractmethod
    def summary(self) -> display.Summary:
        """The result's table (text, HTML in Jupyter)."""

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()


class RefineResult(AbstractRefinement):
    """What :func:`refine` found.

    - `model`: the refined :class:`hbjax.Hammerstein`, normalised (see :func:`refine`).
    - `result`: a :class:`RESULTS` code (``RESULTS.successful`` when converged); `message`
      gives it in words.
    - `stats`: ``{"steps", "cost", "initial_cost", "samples"}``: optimiser steps, mean
      squared residual at the optimum and at the start, residuals used.
    - `covariance`: ``sigma^2 (J^T J)^-1`` mapped to the normalised parameters (order
      a, b, c1, c2 of :func:`hbjax.flatten_params`); singular along the constraint;
      ``inf`` variance for the parameters listed in `unidentified`.
    - `noise_std`: ``sqrt(SSR / (N - q))``, ``q`` the number of free parameters.
    - `branches_cross`: whether the branches cross or meet at some recorded input
      (informational: the model is the core operator ``L = min, H = max`` on the data).
    - `sim_fit`: free-run simulation fit (%) on each estimation record,
      ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)``, simulated from rest as
      :func:`hbjax.simulate` (from the estimated initial state with
      ``initial_state="estimate"``; NaN, shown as "undefined (output constant)", for a
      record whose output never moves); `sim_fit_pooled` over all records
      (``RESULTS.poor_fit`` below :data:`hbjax._identify.quality.SIM_FIT_FLOOR`).
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
    - `residual_p`: p-values (all records pooled, :mod:`hbjax._identify.adequacy`) of the
      one-step prediction errors' whiteness, their independence from past inputs (both
      only where the free-run fit is below the floor, NaN otherwise; :func:`hbjax.resid`
      gives the full analysis of any record; NaN for the simulation criterion), and of
      *no input effect* (the input path against the output's own past; for the
      simulation criterion the free run against it). Above 0.01 the
      last refuses the result (``RESULTS.no_input_effect``). A fit below the floor whose
      errors pass the first two tests is the equation noise integrated by ``1/A``
      dominating the output (poles near 1), not a bad model: it is not refused
      (`noise_limited`).
    - `min_sim_fit`: the floor (%) this result was judged against (the `min_sim_fit` it was
      asked for; the residual tests may overrule only the default floor).
    - `loop_spread`: where the branches cross at recorded inputs where both decide outputs
      (a hysteresis loop closing inside the data; prediction criterion, one-step errors
      passing the residual tests), the free-run fit shortfall (%) the
      estimate's own covariance predicts on the estimation inputs; above the tolerance
      `loop_tolerance` (%, default 1) the result is ``RESULTS.loop_unresolved``
      (:mod:`hbjax._identify.loop`). Both NaN where not judged.
    - `criterion`, `gauge`, `initial_state`: what was minimised, how the gain ambiguity
      was fixed and whether the initial state was estimated.
    """

    criterion: str = eqx.field(static=True)
    gauge: str = eqx.field(static=True)
    initial_state: str = eqx.field(static=True, default="zero")

    def summary(self) -> display.Summary:
        """Estimates, standard errors, 95% intervals, unidentified flags, fit figures and the
        result message; a text table that renders as HTML in Jupyter."""
        return display.estimation_summary(self, "Refinement", covariance=self.covariance)


def summarise(par, z, ssr, ssr0, jtj, n, result, steps, ok):
    """Covariance, noise level, stats and final result code at the optimum ``z``, from the
    sum of squared residuals ``ssr`` (``ssr0`` at the start), ``J^T J`` and the number of
    residuals ``n``.

    ``cov(theta) = D sigma^2 (J^T J)^-1 D^T`` with ``J = dr/dz`` and ``D = dtheta/dz``: the
    usual asymptotic covariance of the least-squares estimate, in the normalised
    parameters (the constraint direction has zero variance). The inverse is taken on the
    directions the data identify, with the same column-normalised rank test that marks
    the others (:func:`hbjax._identify.quality.gauss_newton_inverse`).
    """
    q = z.shape[0]
    noise_var = ssr / jnp.maximum(n - q, 1)  # n: an int, or traced for padded records
    cov_z = noise_var * gauss_newton_inverse(jtj)
    d = par.jacobian()
    cov = d @ cov_z @ d.T
    finite = jnp.all(jnp.isfinite(z)) & jnp.isfinite(ssr)
    result = RESULTS.where(ok, RESULTS.promote(result), RESULTS.gauge_undefined)
    result = RESULTS.where(finite | ~ok, result, RESULTS.nonfinite)
    stats = {"steps": steps, "cost": ssr / n, "initial_cost": ssr0 / n,
             "samples": jnp.asarray(n)}
    return par.model(z), result, stats, cov, jnp.sqrt(noise_var)


def finish(fitted, result, stats, cov, noise_std, par, recordings, criterion, jtj=None,
           min_sim_fit=SIM_FIT_FLOOR):
    """The result with its quality checks, first failing one wins after the solver's own
    code: ``branches_cross`` (a labelled band whose crossing decides an output; refine's
    core finish never leaves one), ``unstable`` (A3), ``no_input_effect`` (the input
    path, or for the simulation criterion the free run, is not significant against the
    output's own past: :mod:`hbjax._identify.adequacy`), ``closing_loop`` / ``poor_fit``
    (free-run fit on the estimation data below ``min_sim_fit``, unless the residual tests
    say the equation noise integrated by ``1/A`` explains it; ``closing_loop`` when the
    branches meet inside the data). Parameters the Gauss-Newton matrix ``jtj`` does not
    identify get ``inf`` variance."""
    theta_s = par.free(flatten_params(fitted))
    consistent, _ = core_consistent(par.theta_scaled(theta_s), par.band, recordings, par.scale,
                                 par.na, par.nb)
    fits, pooled, active, sources = simulation_fit(fitted, recordings, par.initial_state)
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
    nan = jnp.full(3, jnp.nan, pooled.dtype)
    if criterion == PREDICTION:
        no_input = input_effect_p(fitted, recordings, sources, theta_s.shape[0])
        result = RESULTS.where(good & ~(no_input < LEVEL), RESULTS.no_input_effect, result)
        good = result == RESULTS.successful
        # The tests may overrule the default floor, not a floor the caller raised above it.
        # Only a fit below it pays for the whiteness tests (under vmap both branches run).
        default_floor = min_sim_fit <= SIM_FIT_FLOOR
        white = jax.lax.cond(good & poor & default_floor,
                             lambda: whiteness_p(fitted, recordings, sources),
                             lambda: nan[:2])
        residual_p = jnp.concatenate([white, no_input[None]])
    else:  # an output-error fit is not a one-step predictor: its free run is tested
        no_input = simulated_input_effect_p(fitted, recordings, sources, theta_s.shape[0])
        result = RESULTS.where(good & ~(no_input < LEVEL), RESULTS.no_input_effect, result)
        good = result == RESULTS.successful
        residual_p = jnp.concatenate([nan[:2], no_input[None]])
    poor = poor & ~noise_explains(residual_p)
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
                        ident, active, data_range, jnp.asarray(par.core), residual_p,
                        jnp.asarray(min_sim_fit, pooled.dtype),
                        jnp.full((), jnp.nan, pooled.dtype), jnp.full((), jnp.nan, pooled.dtype),
                        criterion,
                        par.gauge, par.initial_state)


def describe(res) -> str:
    """The result code in words; for the quality codes, with the numbers."""
    text = RESULTS[res.result] or "success"
    if res.result == RESULTS.successful and bool(res.noise_limited):
        p = np.asarray(res.residual_p)
        text += (f" (free-run fit {float(res.sim_fit_pooled):.1f} % pooled, below the "
                 f"{float(res.min_sim_fit):g} % floor only because the equation noise integrated by "
                 f"1/A dominates the output: residuals white, p = {p[0]:.2g}, independent of "
                 f"the input, p = {p[1]:.2g}, input path significant, p = {p[2]:.2g})")
    if res.result == RESULTS.poor_fit or res.result == RESULTS.closing_loop:
        fits = ", ".join(display.record_fit_text(f) for f in np.atleast_1d(np.asarray(res.sim_fit)))
        text += (f" (free-run fit {float(res.sim_fit_pooled):.1f} % pooled, per record: "
                 f"{fits}; floor {float(res.min_sim_fit):g} %)")
    elif res.result == RESULTS.loop_unresolved:
        text += (f" (free-run spread {float(res.loop_spread):.3g} % of the output's spread, "
                 f"tolerance {float(res.loop_tolerance):g} %)")
    elif res.result == RESULTS.unstable:
        text += f" (largest pole modulus {res.model.arx.pole_radius():.6g})"
    elif res.result == RESULTS.branches_undetermined:
        text += f" (unidentified: {', '.join(res.unidentified)})"
    elif res.result == RESULTS.free_run_undetermined:
        text += (f" (free-run spread {float(res.free_run_spread):.3g} % of the output's "
                 f"spread, floor {float(res.min_sim_fit):g} %)")
    elif res.result == RESULTS.branches_between_levels:
        text += (f" (a branch's standard deviation between the recorded inputs "
                 f"{float(res.interpolation_ratio):.3g} times its largest at them)")
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


def at_estimated_start(res: "AbstractRefinement", recordings) -> "AbstractRefinement":
    """`res` with `sim_fit` and `sim_fit_pooled` the higher of the solve's figures and
    those from the initial state :func:`hbjax.estimate_initial_state` finds on the records
    as recorded (output lags and play state). The solve's own figure, on records padded to
    a bucket length, fits the past's equation errors with the play operator held at the
    criterion's start: on a slow system (poles 0.97-0.98, ``nb < na``) cut from a longer
    run it read 70.1 % where :func:`hbjax.compare` read 72.3 %, the estimated state's
    figure. Where ``nb > na`` the estimated state holds the input lags at the play state
    and can read lower than the solve's (which the floor was judged on), and compare,
    which fits those lags, reads at least the solve's: the higher figure is compare's in
    both cases, and a success never shows a figure below its floor."""
    # (on the records padded to their buckets: a new record length compiles nothing new)
    fits, pooled, _, _ = simulation_fit(res.model, padded_records(recordings), "estimate",
                                        play_state=True)
    keep = lambda new, old: jnp.where(jnp.isnan(new), old, jnp.maximum(new, old))  # noqa: E731
    return dataclasses.replace(res, sim_fit=keep(fits, res.sim_fit),
                               sim_fit_pooled=keep(pooled, res.sim_fit_pooled))


def fits_better(res: "AbstractRefinement", than: "AbstractRefinement") -> bool:
    """Whether `res` replaces `than`, which the caller solved first: a success over
    anything else, two successes by the higher free-run fit on the estimation records from
    the initial state :func:`hbjax.estimate_initial_state` finds (the same yardstick
    whatever start the criterion assumed); of two failures the first is kept, so the
    reason reported is the first solve's."""
    ok, ok_than = res.result == RESULTS.successful, than.result == RESULTS.successful
    if bool(ok) != bool(ok_than):
        return bool(ok)
    return bool(ok) and bool(res.sim_fit_pooled > than.sim_fit_pooled)
