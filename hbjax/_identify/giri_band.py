"""The closed form's plateau values held to the design's own premise: the branches form a
band at every input the three experiments apply.

Stage 3 of the closed form (eqs. (45)-(46)) observes ``P1*`` only at the rising levels
``[h_m, 2 h_m)`` and ``P2*`` only at the falling ones ``(-2 h_m, -h_m]``. Each branch's values
on the other side (and at ``v1(0) = 0``) are extrapolations of a degree ``m - 1``
interpolant, which amplify the plateau noise by the Lebesgue factor of the extrapolation
(about ``1e4`` for ``m = 5``). The paper's estimate then often has a branch crossing the
other at a level where that one decides the output, or ``P1*(0)`` on the wrong side of
``P1*(h_m)``: the estimated model, simulated on the very experiments it was estimated from,
sticks at the wrong branch for whole records (measured: prediction distances of ``1e4`` to
``1e6 sigma^2`` from the truth for ``m >= 4``, and refinement from there ending in local
minima or failures).

The fix is the least-squares stage under the design's premise: the plateau values ``z``
(P1 at the rising levels, P2 at the falling ones, equal variances) are replaced by their
Euclidean projection onto the polyhedral cone

- ``P1*(x) >= P2*(x)`` at every level and at ``x = 0`` (in the paper's gauge ``mu = 1 > 0``
  the rising branch ``P1*`` is the upper edge: the +-h_m swing crosses the gap),
- ``P1*(0) >= P1*(h_m)`` (the ``v1`` record, from rest at ``v = 0``, reaches ``P1*(h_m)``,
  eq. (17)'s premise),

each branch value being the Lagrange interpolant of its plateau values. Where the paper's
values already satisfy these (the usual case for ``m <= 3`` at small noise) nothing
changes; otherwise the plateau values move by a small fraction of the crossing depth (the
extrapolation's gain is large), well inside their noise, while the extrapolations stop
deciding outputs they never produced. The projection is a non-negative least-squares
problem in the multipliers (Moreau: ``p = z + G^T lambda``,
``lambda = argmin_{lambda >= 0} ||G^T lambda + z||``), solved exactly (Lawson-Hanson,
:func:`scipy.optimize.nnls`) on the host; it runs under ``jit`` and ``vmap``.
"""

import jax
import jax.numpy as jnp
import numpy as np


def _lagrange(nodes, x):
    """``L[k, j]``: the ``j``-th Lagrange basis polynomial on ``nodes`` at ``x[k]``."""
    nodes, x = np.asarray(nodes, float), np.asarray(x, float)
    out = np.ones((x.shape[0], nodes.shape[0]))
    for j, xj in enumerate(nodes):
        for i, xi in enumerate(nodes):
            if i != j:
                out[:, j] *= (x - xi) / (xj - xi)
    return out


def band_constraints(levels_scaled, m: int) -> np.ndarray:
    """Rows ``G`` (unit norm) of the cone ``G p >= 0`` for ``p = [P1* at levels[:m],
    P2* at levels[m:]]`` (levels in ``x = v / h_m``; ``levels[0] = 1`` is ``+h_m``)."""
    lv = np.asarray(levels_scaled, float)
    rise, fall = lv[:m], lv[m:]
    points = np.concatenate([lv, [0.0]])
    crossing = np.concatenate([_lagrange(rise, points), -_lagrange(fall, points)], axis=1)
    start = np.zeros((1, 2 * m))
    start[0, :m] = _lagrange(rise, np.zeros(1))[0]
    start[0, 0] -= 1.0  # P1*(0) - P1*(h_m)
    g = np.concatenate([crossing, start], axis=0)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def _project_rows(g, z):
    """Every row of ``z`` (any leading batch axes) projected onto the cone ``g z >= 0`` by
    non-negative least squares, rows already inside it (or not finite) left as they are:
    one host call per batch under ``vmap`` instead of one per realisation (a Monte Carlo
    study's closed form took twice as long with a callback per realisation)."""
    z = np.asarray(z)
    rows = z.reshape(-1, z.shape[-1]).astype(float)
    out = rows.copy()
    need = np.all(np.isfinite(rows), axis=1) & np.any(rows @ g.T < 0, axis=1)
    if need.any():  # (scipy.optimize would add 0.4 s to `import hbjax`)
        from scipy.optimize import nnls
    for k in np.flatnonzero(need):
        lam, _ = nnls(g.T, -rows[k], maxiter=50 * g.shape[0])
        out[k] = rows[k] + g.T @ lam
    return out.reshape(z.shape).astype(z.dtype)


def _require_host_backend():
    """The projection is a host callback: JAX needs its CPU backend for it, also when the
    computation runs on an accelerator. Without one, JAX fails only when the call runs,
    with an internal error; this says so at trace time, with the fix."""
    try:
        jax.devices("cpu")
    except RuntimeError:
        raise RuntimeError(
            "the closed form's band projection runs on the host and needs JAX's CPU backend: "
            "list cpu beside the accelerator (JAX_PLATFORMS=cuda,cpu) or leave JAX_PLATFORMS "
            "unset.") from None


def project_onto_band(z, levels_scaled, m: int, orientation_ok):
    """``z`` (2m plateau values) projected onto the design's band cone
    (:func:`band_constraints`); unchanged where ``orientation_ok`` is False (a gap of the
    wrong sign: the closed form fails with ``gap_not_crossed`` anyway)."""
    _require_host_backend()
    g = band_constraints(levels_scaled, m)
    shape = jax.ShapeDtypeStruct(z.shape, z.dtype)
    projected = jax.pure_callback(lambda zz: _project_rows(g, zz), shape, z,
                                  vmap_method="expand_dims")
    return jnp.where(orientation_ok, projected, z)
