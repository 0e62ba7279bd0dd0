"""Separable least squares (variable projection), the baseline of Bai (Automatica 2002) for
hard input nonlinearities: for fixed backlash parameters the internal signal ``u`` is known
and the ARX parameters follow by linear least squares; only the backlash parameters are
searched (here by Levenberg–Marquardt on the projected residual, Golub–Pereyra)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._core.arx import ARX
from .._core.backlash import Backlash
from .._misc import check_bool, is_traced, positive_float, positive_int
from .._core.cache import ensure_compilation_cache
from .._core.precision import require_x64
from .linear import arx_regressors, equilibrated_solve
from .lm import levenberg_marquardt
from .criteria import PREDICTION, internal_signal, lower_is_p1
from .._core.model import Hammerstein
from .._core.params import flatten_params
from .recordings import as_recordings, check_h_m, check_model, total_samples
from .._results import RESULTS, raise_if_failed
from .refine import check_gauge
from .refine_result import RefinementError, RefineResult, finish, summarise
from .units import in_unit, model_in_unit, output_unit, result_from_unit
from .refine_solve import flat_residuals, gauge_transform, make_parametrisation, residual_summary


def _regressors(theta_c, x, y, lower, na, nb):
    """``phi(t) = [-y(t-1..na), u(t-1..nb)]`` of eq. (10) with ``u = HB(v)`` for the
    backlash coefficients ``theta_c = [c1, c2]`` (the ARX slots are unused)."""
    theta = jnp.concatenate([jnp.zeros(na + nb), theta_c])
    return arx_regressors(internal_signal(theta, x, lower, na, nb), y, na, nb)


def linear_part(theta_c, recordings, scale, lower, na, nb):
    """The ARX parameters minimising the prediction errors for fixed backlash (linear LS,
    normal equations with equilibration; differentiable in ``theta_c``)."""
    gram, rhs = 0.0, 0.0
    for v, y in recordings:
        phi = _regressors(theta_c, v / scale, y, lower, na, nb)
        gram = gram + phi.T @ phi
        rhs = rhs + phi.T @ y
    return equilibrated_solve(gram, rhs, differentiable=True)


def _projected_residuals(w, args):
    """Variable-projection residual ``y - phi(c) theta_lin(c)`` for ``c = c_p + U w``."""
    c_p, basis, recordings, scale, lower, na, nb = args
    theta_c = c_p + basis @ w
    theta_lin = linear_part(theta_c, recordings, scale, lower, na, nb)
    return tuple(y - _regressors(theta_c, v / scale, y, lower, na, nb) @ theta_lin
                 for v, y in recordings)


def _constraint_basis(g):
    """Particular solution and orthonormal null-space basis of ``g^T c = 1``."""
    _, _, vt = jnp.linalg.svd(g[None, :])
    return g / jnp.dot(g, g), vt[1:].T


def separable_traceable(model: Hammerstein, recordings, *, h_m=None, max_steps: int = 256,
                        rtol: float = 1e-7, atol: float = 1e-7) -> RefineResult:
    """Traceable core of :func:`separable_ls` (never raises; code in ``.result``); solved
    on the outputs in their own unit as :func:`hbjax._identify.refine.refine_traceable`."""
    unit = output_unit(recordings)
    res = _separable_in_unit(model_in_unit(model, unit), in_unit(recordings, unit), h_m=h_m,
                             max_steps=max_steps, rtol=rtol, atol=atol)
    return result_from_unit(res, unit)


def _separable_in_unit(model, recordings, *, h_m, max_steps, rtol, atol):
    na, nb, m = model.arx.na, model.arx.nb, model.backlash.m
    par = make_parametrisation(model, recordings, h_m)
    start, ok = gauge_transform(model, par)
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower_is_p1(start, recordings))
    powers = jnp.concatenate([par.scale ** jnp.arange(m)] * 2)
    c0 = jnp.concatenate([start.backlash.c1, start.backlash.c2]) * powers
    if h_m is None:
        # The linear block absorbs any scale of the backlash: hold the component of the
        # scaled coefficients along their initial value fixed, map to B(1) = 1 at the end.
        g = c0 / jnp.dot(c0, c0)
    else:
        g = par.constraint_row()[na + nb:] / powers  # P2(-h_m) - P1(h_m) = 1, scaled
    c_p, basis = _constraint_basis(g)
    w0 = basis.T @ (c0 - c_p)
    args = (c_p, basis, recordings, par.scale, par.lower_is_p1, na, nb)
    sol = levenberg_marquardt(_projected_residuals, w0, args, max_steps=max_steps, rtol=rtol,
                              atol=atol, norm=optx.max_norm, normal_cholesky=True)
    theta_c = (c_p + basis @ sol.value) / powers
    theta_lin = linear_part(theta_c * powers, recordings, par.scale, par.lower_is_p1, na, nb)
    found = Hammerstein(Backlash(theta_c[:m], theta_c[m:]), ARX(theta_lin[:na], theta_lin[na:]))
    found, ok_end = gauge_transform(found, par)
    z = par.free(flatten_params(found))
    z0 = par.free(flatten_params(start))
    r = flat_residuals(z, par, recordings, PREDICTION)
    jac = jax.jacfwd(flat_residuals)(z, par, recordings, PREDICTION)
    ssr, ssr0, jtj = residual_summary(par, z0, r, jac, recordings, PREDICTION)
    fitted, result, stats, cov, noise_std = summarise(
        par, z, ssr, ssr0, jtj, r.shape[0], sol.result, sol.stats["num_steps"], ok & ok_end)
    return finish(fitted, result, stats, cov, noise_std, par, recordings, PREDICTION, jtj)


_separable_jit = jax.jit(separable_traceable, static_argnames=("max_steps", "rtol", "atol"))


def separable_ls(model: Hammerstein, recordings, *, h_m=None, max_steps: int = 256,
                 rtol: float = 1e-7, atol: float = 1e-7, throw: bool = True) -> RefineResult:
    """Separable nonlinear least squares (variable projection) for the prediction-error
    criterion, after Bai (Automatica 2002).

    For fixed backlash coefficients ``(c1, c2)`` the internal signal ``u = HB(v)`` is
    known and eq. (10) is a linear regression in ``(a, b)``: they are eliminated by linear
    least squares, and Levenberg–Marquardt searches only the ``2m - 1`` free backlash
    coefficients on the projected residual. The minimiser is the same as that of
    :func:`hbjax.refine` with ``criterion="prediction"`` (it is the same cost); the search
    space, and so the cost per step and the basin of attraction, differ.

    Normalisation as :func:`hbjax.refine`: ``P2(-h_m) - P1(h_m) = 1`` with `h_m`,
    ``B(1) = 1`` without. Only the backlash (and the orders) of `model` are used as the
    start. Returns a :class:`hbjax.RefineResult` (``stats["steps"]`` counts the
    projected-problem steps; the covariance is that of the full parameter vector).
    """
    require_x64("separable_ls")
    ensure_compilation_cache()
    throw = check_bool(throw, "throw")
    check_model(model)
    recs = as_recordings(recordings, model=model)
    h_m = check_h_m(h_m)
    max_steps = positive_int(max_steps, "max_steps")
    q = flatten_params(model).shape[0] - 1
    if total_samples(recs) <= q:
        raise ValueError(f"`recordings` hold {total_samples(recs)} samples; {q} free "
                         "parameters need more.")
    if not any(is_traced(x) for x in jax.tree_util.tree_leaves(model)):
        check_gauge(model, h_m)
    res = _separable_jit(model, recs, h_m=h_m, max_steps=max_steps, rtol=positive_float(rtol, "rtol"),
                         atol=positive_float(atol, "atol"))
    if throw and is_traced(res.result._value):
        return raise_if_failed(res)
    if throw and res.result != RESULTS.successful:
        raise RefinementError(f"separable_ls did not converge: {res.message}.")
    return res
