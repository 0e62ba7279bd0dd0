"""The Levenberg–Marquardt set-up of refinement: the gauge fixed on the start, the free
parameters' residuals, one solve under a parametrisation's band rule (by the sufficient
statistics of :mod:`hbjax._identify.sufficient` where that is exact, else on the full
residual) and ``(SSR, SSR at the start, J^T J)`` at its optimum.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .._core.arx import ARX
from .._core.backlash import Backlash
from .._core.model import Hammerstein
from .._core.params import gauge_factor
from .criteria import PREDICTION, data_scale, residuals
from .parametrisation import PAPER, STATIC_GAIN, Parametrisation
from .lm import levenberg_marquardt
from .sufficient import gauss_newton_matrix, solve_by_statistics, worth_it


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


def flat_residuals(z, par, recordings, criterion):
    return jnp.concatenate(residuals(z, par, recordings, criterion))


def solve(par: Parametrisation, z0, recordings, criterion, *, max_steps, rtol, atol):
    """Levenberg–Marquardt on the free parameters; never raises."""

    def fn(z, args):
        return residuals(z, *args, criterion)

    return levenberg_marquardt(fn, z0, (par, recordings), max_steps=max_steps, rtol=rtol,
                               atol=atol, norm=optx.max_norm, normal_cholesky=True)


def _at_optimum(sol, par, recordings, criterion):
    """Residuals and Jacobian at the solution: optimistix keeps both for the last accepted
    point in its state (saves one evaluation); recomputed if that internal layout changes."""
    f_info = getattr(sol.state, "f_info", None)
    if isinstance(f_info, optx.FunctionInfo.ResidualJac):
        return jnp.concatenate(f_info.residual), lx.materialise(f_info.jac).as_matrix()
    z = sol.value
    return (flat_residuals(z, par, recordings, criterion),
            jax.jacfwd(flat_residuals)(z, par, recordings, criterion))


def residual_summary(par, z0, r, jac, recordings, criterion):
    """``(SSR, SSR at z0, J^T J)`` of a solver that evaluates the full residual."""
    r0 = flat_residuals(z0, par, recordings, criterion)
    return jnp.sum(r**2), jnp.sum(r0**2), jac.T @ jac


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


# A nested jit: refinement calls this up to six times with the same shapes (first solve,
# reorientation, touches, core finish, core solve from the start); JAX traces and lowers it
# once per signature instead of once per call, which is most of a cached cold start
# (refine: 3.9 -> 2.7 s of tracing and lowering, benchmarks/cold_start.py).
@eqx.filter_jit
def solve_criterion(par, z0, recordings, criterion, statistics, options):
    """One Levenberg–Marquardt solve under ``par``'s band rule:
    ``(z, result, steps, SSR, SSR0, J^T J)``."""
    # (the statistics cover every sample: not with the first ones left out)
    if (criterion == PREDICTION and statistics and par.initial_state == "zero"
            and worth_it(par.na, par.nb, par.m)):
        return _solve_prediction(par, z0, recordings, **options)
    return _solve_full(par, z0, recordings, criterion, **options)
