"""Prediction-error / output-error refinement of an HB-Hammerstein model with optimistix.

``refine`` minimises the sum of squared one-step prediction errors (the maximum-likelihood
criterion under the paper's Gaussian equation error, eq. (10)) or of output errors (free run)
over the normalised parameters, with Levenberg–Marquardt through the differentiable play
operator and ARX recursion. ``refine_traceable`` is its jit/vmap-able core.
"""

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
from .._core.precision import require_x64
from .criteria import (
    PAPER, PREDICTION, STATIC_GAIN, Parametrisation, band_violated, data_scale, lower_is_p1,
    residuals,
)
from .._core.model import Hammerstein
from .._core.params import flatten_params
from .recordings import as_recordings, check_criterion, check_h_m, check_model, total_samples
from .sufficient import gauss_newton_matrix, solve_by_statistics, worth_it


class RESULTS(optx.RESULTS):  # pyright: ignore
    """Optimistix result codes plus the ones specific to refinement."""

    gauge_undefined = (
        "the normalisation cannot be applied to the initial model: mu = P2(-h_m) - P1(h_m) "
        "is 0 (paper gauge) or B(1) is 0 (static-gain gauge)"
    )
    branches_cross = (
        "the refined branches P1 and P2 cross at recorded inputs: the estimate is not a "
        "hysteresis band over the data (too little excitation of the inactive branch, or "
        "a wrong branch degree m)"
    )


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
    - `branches_cross`: whether the band's lower edge exceeds its upper edge at some
      recorded input (then `result` is ``RESULTS.branches_cross``).
    - `criterion`, `gauge`: what was minimised and how the gain ambiguity was fixed.
    """

    model: Hammerstein
    result: RESULTS
    stats: dict
    covariance: Float[Array, "p p"]
    noise_std: Float[Array, ""]
    branches_cross: Bool[Array, ""]
    criterion: str = eqx.field(static=True)
    gauge: str = eqx.field(static=True)

    @property
    def message(self) -> str:
        """The result code in words (concrete results only)."""
        return RESULTS[self.result] or "success"

    @property
    def std(self) -> Float[Array, " p"]:
        """Standard errors (square roots of the covariance diagonal)."""
        return jnp.sqrt(jnp.maximum(jnp.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))

    def summary(self) -> display.Summary:
        """Estimates, standard errors, 95% intervals, unidentified flags, fit figures and the
        result message; a text table that renders as HTML in Jupyter."""
        return display.estimation_summary(self, "Refinement", covariance=self.covariance)

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()


def gauge_transform(model: Hammerstein, par: Parametrisation):
    """``(A, mu B, P/mu)`` in the gauge of ``par`` and whether ``mu`` was usable.

    Paper gauge: ``mu = P2(-h_m) - P1(h_m)`` (section 4.1); static-gain gauge:
    ``mu = 1 / B(1)``. Traceable: a zero ``mu`` gives ``ok = False``, never NaN.
    """
    bl, arx = model.backlash, model.arx
    if par.gauge == PAPER:
        mu = bl.p2(-par.h_m) - bl.p1(par.h_m)
        ok = jnp.isfinite(mu) & (mu != 0)
        inv = 1.0 / jnp.where(ok, mu, 1.0)
        mu = jnp.where(ok, mu, 1.0)
    else:
        gain = jnp.sum(arx.b)
        ok = jnp.isfinite(gain) & (gain != 0)
        inv = jnp.where(ok, gain, 1.0)
        mu = 1.0 / inv
    return Hammerstein(Backlash(bl.c1 * inv, bl.c2 * inv), ARX(arx.a, arx.b * mu)), ok


def make_parametrisation(model, recordings, h_m, lower=True) -> Parametrisation:
    gauge = STATIC_GAIN if h_m is None else PAPER
    h = jnp.asarray(0.0 if h_m is None else h_m, jnp.float64)
    return Parametrisation(model.arx.na, model.arx.nb, model.backlash.m, gauge,
                           data_scale(recordings), h, jnp.asarray(lower))


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
    noise_var = ssr / max(n - q, 1)
    cov_z = noise_var * jnp.linalg.pinv(jtj, hermitian=True)
    d = par.jacobian()
    cov = d @ cov_z @ d.T
    finite = jnp.all(jnp.isfinite(z)) & jnp.isfinite(ssr)
    result = RESULTS.where(ok, RESULTS.promote(result), RESULTS.gauge_undefined)
    result = RESULTS.where(finite | ~ok, result, RESULTS.nonfinite)
    stats = {"steps": steps, "cost": ssr / n, "initial_cost": ssr0 / n,
             "samples": jnp.asarray(n)}
    return par.model(z), result, stats, cov, jnp.sqrt(noise_var)


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


def refine_traceable(model: Hammerstein, recordings, *, criterion: str = "prediction",
                     h_m=None, max_steps: int = 256, rtol: float = 1e-7,
                     atol: float = 1e-7, statistics: bool = True) -> RefineResult:
    """Traceable core of :func:`refine`: no checks, never raises, result code in `.result`.

    With ``statistics=True`` (default) the prediction criterion is solved on the Gram matrix
    of its bilinear regressors, one pass over the data per round (:mod:`hbjax._identify.sufficient`),
    with the full solve as fallback, for orders whose Gram matrix is small
    (``1 + na + 2 m nb <= 32``); ``statistics=False`` always takes a pass per
    Levenberg–Marquardt step (used by multi-start fitting under ``vmap``, where the
    fallback's ``lax.cond`` would run both branches).

    ``recordings`` must already be a tuple of ``(v, y)`` float64 array pairs. Works under
    ``jax.jit`` and ``jax.vmap`` (e.g. over noise realisations with the inputs shared);
    see :func:`refine_batch`.
    """
    par = make_parametrisation(model, recordings, h_m)
    start, ok = gauge_transform(model, par)
    # The band's orientation is taken from the (normalised) start and kept fixed.
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower_is_p1(start, recordings))
    z0 = par.free(flatten_params(start))
    options = dict(max_steps=max_steps, rtol=rtol, atol=atol)
    if criterion == PREDICTION and statistics and worth_it(par.na, par.nb, par.m):
        z, result, steps, ssr, ssr0, jtj = _solve_prediction(par, z0, recordings, **options)
    else:
        z, result, steps, ssr, ssr0, jtj = _solve_full(par, z0, recordings, criterion, **options)
    n = total_samples(recordings)
    fitted, result, stats, cov, noise_std = summarise(par, z, ssr, ssr0, jtj, n, result,
                                                      steps, ok)
    return finish(fitted, result, stats, cov, noise_std, par, recordings, criterion)


def finish(fitted, result, stats, cov, noise_std, par, recordings, criterion):
    """The result, failing with ``branches_cross`` where the band is not a band."""
    crossed = band_violated(fitted, recordings, par.lower_is_p1)
    result = RESULTS.where(crossed & (result == RESULTS.successful), RESULTS.branches_cross,
                           result)
    return RefineResult(fitted, result, stats, cov, noise_std, crossed, criterion, par.gauge)


@eqx.filter_jit
def _refine_jit(model, recordings, criterion, h_m, max_steps, rtol, atol):
    return refine_traceable(model, recordings, criterion=criterion, h_m=h_m,
                            max_steps=max_steps, rtol=rtol, atol=atol)


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
    # NumPy, not jnp: inside jit even constant jnp operations are traced.
    poly = np.polynomial.polynomial.polyval
    mu = float(poly(-h_m, np.asarray(bl.c2)) - poly(h_m, np.asarray(bl.c1)))
    if mu == 0.0 or not np.isfinite(mu):
        raise ValueError(
            f"mu = P2(-h_m) - P1(h_m) is {mu} for the initial `model` and `h_m` = {h_m}: "
            "the paper's normalisation (section 4.1) cannot be applied; the +-h_m swing "
            "must cross the backlash gap."
        )


def refine(model: Hammerstein, recordings, *, criterion: str = "prediction", h_m=None,
           max_steps: int = 256, rtol: float = 1e-7, atol: float = 1e-7,
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

    The band stays a band: the branch that is lower on average over the data for the
    (normalised) initial model is the lower edge ``L`` throughout the solve (a labelled
    band, smooth in the parameters, where ``L = min, H = max`` would have a kink each time
    an estimate's branches touch at a recorded input and trap the solver there). If the
    refined branches cross at a recorded input the result is ``RESULTS.branches_cross``
    (``.branches_cross`` is True); otherwise the returned model is exactly the core's
    ``L = min(P1, P2)``, ``H = max(P1, P2)`` operator on the data. Orders are static.

    **Arguments:**

    - `model`: initial :class:`hbjax.Hammerstein` (e.g. from :func:`hbjax.identify_giri`);
      its orders ``na, nb, m`` are kept. It is first mapped to the chosen normalisation.
    - `recordings`: one ``(v, y)`` pair or a list of pairs (several experiments, any
      input signals, lengths may differ between experiments).
    - `criterion`: ``"prediction"`` or ``"simulation"``.
    - `h_m`: amplitude of the paper's design, selects the normalisation (above).
    - `max_steps`, `rtol`, `atol`: Levenberg–Marquardt limits and tolerances (in the
      scaled free parameters and residuals).
    - `throw`: raise :class:`RefinementError` if the solve did not converge (default);
      otherwise inspect ``.result`` / ``.message``.

    **Returns:** a :class:`RefineResult`.
    """
    require_x64("refine")
    check_model(model)
    check_criterion(criterion)
    recs = as_recordings(recordings)
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
    res = _refine_jit(model, recs, criterion, h_m, max_steps, positive_float(rtol, "rtol"), positive_float(atol, "atol"))
    if throw and not is_traced(res.result._value) and res.result != RESULTS.successful:
        raise RefinementError(
            f"refine ({criterion} criterion) did not converge: {res.message} "
            f"(steps {int(res.stats['steps'])}, mean squared residual "
            f"{float(res.stats['cost']):.4g}); pass throw=False to inspect the result."
        )
    return res
