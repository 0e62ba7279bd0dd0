"""The ARX block given its input: the regressors of eq. (10) and their least squares.

With the internal signal ``u`` known (a backlash start in :func:`hbjax.fit`, the current
branches in separable least squares, the binary internal signal of the closed form's
second experiment, eq. (23)) the equation error ``y(t) - phi(t)^T [a; b]`` is linear in
``a, b``. Every estimator builds ``phi`` here and solves through
:func:`arx_least_squares` or, where it also needs the condition number and the
covariance (the closed form's eq. (26)), :func:`equilibrate` and
:func:`equilibrated_solve`.
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._misc import lagged


def arx_regressors(u: Float[Array, " time"], y: Float[Array, " time"], na: int,
                   nb: int) -> Float[Array, "time na+nb"]:
    """``phi(t) = [-y(t-1), ..., -y(t-na), u(t-1), ..., u(t-nb)]`` (zero before ``t = 0``),
    the regressors of eq. (10): ``y(t) = phi(t)^T [a; b] + xi(t)``."""
    cols = [-lagged(y, i + 1) for i in range(na)] + [lagged(u, i + 1) for i in range(nb)]
    return jnp.stack(cols, axis=1)


def equilibrate(gram):
    """``(gram / outer(s, s), s)`` with ``s = sqrt(diag(gram))``: the normal equations
    scaled to a unit diagonal, so that their condition number reflects the design, not
    the units of ``y`` and ``u``."""
    scale = jnp.sqrt(jnp.maximum(jnp.diagonal(gram), 1e-300))
    return gram / jnp.outer(scale, scale), scale


def equilibrated_solve(gram, rhs, *, differentiable: bool = False):
    """``gram^-1 rhs`` solved on the equilibrated normal equations (:func:`equilibrate`).

    ``differentiable=False`` uses ``lstsq`` (the minimum-norm solution where a start
    leaves the regression singular); ``True`` uses ``solve``, whose derivative the
    separable least squares differentiates through.
    """
    scaled, scale = equilibrate(gram)
    if differentiable:
        return jnp.linalg.solve(scaled, rhs / scale) / scale
    return jnp.linalg.lstsq(scaled, rhs / scale)[0] / scale


def arx_least_squares(records, na: int, nb: int, *, skip: int = 0,
                      differentiable: bool = False,
                      constant: bool = False) -> Float[Array, " na+nb"]:
    """``[a; b]`` minimising the equation errors of all records ``(u, y)`` at once (the
    normal equations summed over records, each record's first ``skip`` rows left out);
    see :func:`equilibrated_solve` for ``differentiable``. ``constant=True`` adds a
    constant regressor (an offset in the equation) and returns ``[a; b; offset]``.
    A record ``(u, y, mask)`` counts only the rows `mask` marks (a record padded to a
    bucket length, :func:`hbjax._identify.criteria.unpack`)."""
    gram, rhs = 0.0, 0.0
    for u, y, *mask in records:
        phi = arx_regressors(u, y, na, nb)
        if constant:
            phi = jnp.concatenate([phi, jnp.ones((phi.shape[0], 1), phi.dtype)], axis=1)
        if mask and mask[0] is not None:
            phi = jnp.where(mask[0][:, None], phi, 0.0)
        phi = phi[skip:]
        gram = gram + phi.T @ phi
        rhs = rhs + phi.T @ y[skip:]
    return equilibrated_solve(gram, rhs, differentiable=differentiable)
