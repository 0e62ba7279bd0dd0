"""How precisely an estimate determines its free-run simulation.

The covariance a refinement or fit reports is that of the parameters; what a user compares
with a validation record is the simulated output. First-order propagation carries one to the
other: the standard deviation of ``y_sim(t)`` is ``sqrt(diag(J C J^T))`` with
``J = d y_sim / d theta`` (``theta`` as :func:`hbjax.flatten_params`). On closing-loop
systems this predicted spread matches the validation shortfalls measured against the true
system (``benchmarks/closing_uncertainty.py``; numbers in ``benchmarks/RESULTS.md``).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._core.model import Hammerstein
from .._core.params import flatten_params, unflatten_params
from .._core.simulate import simulate
from .._misc import as_float_array


def free_run_std(model: Hammerstein, covariance: Float[Array, "p p"], v, *, u0=0.0,
                 y0=None) -> Float[Array, " time"]:
    """Standard deviation, sample by sample, of ``hbjax.simulate(model, v, u0=u0, y0=y0)``
    implied by the parameter `covariance` (the asymptotic covariance of the estimate, in the
    order of :func:`hbjax.param_names`): ``sqrt(diag(J C J^T))``, ``J`` the Jacobian of the
    free run (eqs. (1)-(2) through the play operator) with respect to the parameters.

    A parameter the data do not identify (``inf`` variance, listed in a result's
    ``.unidentified``) makes the spread ``inf`` at every sample whose output it moves: the
    estimate says nothing there.

    **Returns:** an array shaped like `v`.
    """
    v = as_float_array(v, "v", ndim=1)
    cov = jnp.asarray(covariance)
    theta = flatten_params(model)
    if cov.shape != (theta.shape[0], theta.shape[0]):
        raise ValueError(f"`covariance` must be {theta.shape[0]} x {theta.shape[0]} (one row per "
                         f"parameter of `model`), got shape {cov.shape}.")
    return jnp.sqrt(free_run_variance(model, cov, v, u0=u0, y0=y0))


def free_run_variance(model: Hammerstein, covariance, v, *, u0=0.0, y0=None):
    """``diag(J C J^T)`` of :func:`free_run_std` without its checks (traceable; ``inf``
    where a parameter of infinite variance moves the output)."""
    theta = flatten_params(model)

    def free_run(t):
        return simulate(unflatten_params(model, t), v, u0=u0, y0=y0)

    jac = jax.jacfwd(free_run)(theta)
    cov = jnp.asarray(covariance)
    unknown = ~jnp.isfinite(jnp.diagonal(cov))
    var = jnp.einsum("tp,pq,tq->t", jac, jnp.where(jnp.isfinite(cov), cov, 0.0), jac)
    moved = jnp.any((jac != 0) & unknown[None, :], axis=1)
    return jnp.where(moved, jnp.inf, jnp.maximum(var, 0.0))
