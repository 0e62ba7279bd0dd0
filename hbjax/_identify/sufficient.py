"""Prediction-error refinement through sufficient statistics.

The play operator's output is a branch value at a past input (:func:`hbjax._identify.criteria._internal`):
``u(t) = G(t) c`` with ``G(t)`` the row of powers ``x(s)^i`` of the *source* instant ``s`` on
its branch and ``c = [c1, c2]``. While the sources stay fixed, the one-step prediction error
of eq. (10) is bilinear in the parameters,

    r = y + sum_i a_i y(t-i) - sum_j b_j G(t-j) c = M w,
    M = [y, y(t-1), ..., y(t-na), G(t-1), ..., G(t-nb)],
    w = [1, a, -b_1 c, ..., -b_nb c],

so ``||r||^2 = w^T (M^T M) w`` needs only the small Gram matrix ``M^T M`` (``1 + na + 2 m nb``
square). Levenberg–Marquardt then runs on the short residual ``F w`` (``F^T F = M^T M``)
instead of the ``T``-long one, and a *round* (one pass over the data) recomputes the
sources and the Gram at its solution. When a round leaves every source as it was, the frozen
cost and the true cost coincide around the solution: it is a minimum of the true
prediction-error cost, the one :func:`hbjax._identify.refine_solve.solve` finds with a pass per step.
"""

import jax
import jax.numpy as jnp
import optimistix as optx

from .._core.backlash import power_columns
from .._misc import lag_sum, lagged
from .criteria import branch_sources, unpack, where_valid
from .parametrisation import Parametrisation
from .lm import levenberg_marquardt

# Rounds after which sources that still move hand over to the full solve. From a start far
# from the optimum under an input whose switching instants depend on the band, each round
# moves the sources a little and the rounds converge slowly; a full solve is faster there.
MAX_ROUNDS = 4
# Largest Gram matrix (1 + na + 2 m nb) worth it: a round costs T d^2 against T q per step of
# the full solve (q = na + nb + 2m - 1 free parameters). Measured on 10 000 samples: d = 15
# and 29 were 2.8-3.2x and 1.6-2.7x faster than the full solve, d = 45 and 89 slower.
MAX_GRAM_SIZE = 32


def gram_size(na: int, nb: int, m: int) -> int:
    """Columns of ``M``: ``1 + na + 2 m nb``."""
    return 1 + na + 2 * m * nb


def worth_it(na: int, nb: int, m: int) -> bool:
    """Whether the orders make the Gram path cheaper than the full solve."""
    return gram_size(na, nb, m) <= MAX_GRAM_SIZE


def statistics(z, par: Parametrisation, recordings):
    """At free parameters ``z``: the Gram matrix ``sum_k M_k^T M_k`` over the records, the
    source code of every sample (``4 s + 2 [on P1] + [on P2]``; 0 while the output is still
    ``u(-1)``) and the sum of squared prediction errors ``||M w||^2``
    (:func:`source_codes`, :func:`gram_from_codes`)."""
    codes, ssr = source_codes(z, par, recordings)
    return gram_from_codes(codes, par, recordings), codes, ssr


def source_codes(z, par: Parametrisation, recordings):
    """The source code of every sample at ``z`` (see :func:`statistics`; records
    concatenated) and the sum of squared prediction errors ``||M w||^2``: one play-operator
    pass per record, no Gram.

    The sum is taken from the residual itself, ``A(q^-1) y - B(q^-1) u`` (``= M w``):
    ``w^T (M^T M) w`` cancels ``||y||^2`` against the fit and loses the small costs of
    low-noise data (measured: 0.7% at noise std 1e-5, 0 instead of 1e-16 at 1e-8)."""
    theta = par.theta_scaled(z)
    a, b = theta[:par.na], theta[par.na:par.na + par.nb]
    codes, ssr = [], 0.0
    for v, y, mask in map(unpack, recordings):
        u, idx, on_p1, on_p2 = branch_sources(theta, v / par.scale, par.na, par.nb, par.band)
        r = y + lag_sum(a, y) - lag_sum(b, u)
        ssr = ssr + jnp.sum(where_valid(mask, r, 0.0) ** 2)
        code = 4 * idx + 2 * on_p1.astype(jnp.int32) + on_p2.astype(jnp.int32)
        codes.append(where_valid(mask, code, 0))
    return jnp.concatenate(codes), ssr


def gram_from_codes(codes, par: Parametrisation, recordings):
    """The Gram matrix ``sum_k M_k^T M_k`` of the sources ``codes`` (:func:`source_codes`).
    ``M`` depends on the parameters only through the sources: a round that leaves every
    source as it was keeps its Gram without this pass."""
    na, nb, m = par.na, par.nb, par.m
    gram, start = 0.0, 0
    for v, y, mask in map(unpack, recordings):
        code = jax.lax.dynamic_slice_in_dim(codes, start, v.shape[0])
        start += v.shape[0]
        xs = (v / par.scale)[code // 4]
        powers = power_columns(xs, m)
        g = jnp.concatenate([powers * ((code // 2) % 2)[:, None].astype(xs.dtype),
                             powers * (code % 2)[:, None].astype(xs.dtype)], axis=1)
        cols = ([y[:, None]] + [lagged(y, i + 1)[:, None] for i in range(na)]
                + [lagged(g, j + 1) for j in range(nb)])
        # A padded record's rows beyond its samples are zero: they add nothing to the Gram.
        design = where_valid(mask, jnp.concatenate(cols, axis=1), 0.0)
        gram = gram + jnp.matmul(design.T, design, precision=jax.lax.Precision.HIGHEST)
    return gram


def bilinear_weights(z, par: Parametrisation):
    """``w = [1, a, -b_1 c, ..., -b_nb c]`` (scaled branch coefficients)."""
    theta = par.theta_scaled(z)
    a, b, c = theta[:par.na], theta[par.na:par.na + par.nb], theta[par.na + par.nb:]
    return jnp.concatenate([jnp.ones(1, theta.dtype), a, -(b[:, None] * c[None, :]).ravel()])


def gram_factor(gram):
    """``F`` with ``F^T F = gram`` (symmetric square root; the Gram may be singular)."""
    lam, vec = jnp.linalg.eigh(gram)
    return (vec * jnp.sqrt(jnp.maximum(lam, 0.0))).T


def gauss_newton_matrix(z, par, gram):
    """``J^T J`` of the full residual ``r = M w(z)``: ``D^T (M^T M) D``, ``D = dw/dz``."""
    d = jax.jacfwd(bilinear_weights)(z, par)
    return d.T @ gram @ d


def _reduced_residual(z, args):
    par, factor = args
    return factor @ bilinear_weights(z, par)


def solve_by_statistics(par: Parametrisation, z0, recordings, *, max_steps, rtol, atol):
    """Rounds of Levenberg–Marquardt on the frozen-source cost until the sources settle.

    Each round may take up to ``max_steps`` Levenberg–Marquardt steps; no new round starts
    once the rounds together have taken ``max_steps`` (if the sources still move then, the
    result is ``nonlinear_max_steps_reached``).

    Returns ``(z, result, steps, gram, ssr, unsettled, ssr0)``: the solution, the optimistix
    result, the steps of all rounds, the Gram matrix and the sum of squared prediction errors
    at ``z``, whether the sources still moved after :data:`MAX_ROUNDS` rounds within the step
    budget (then the caller finishes with the full solve), and the sum of squares at ``z0``."""
    gram0, codes0, ssr0 = statistics(z0, par, recordings)
    ok = optx.RESULTS.successful

    def round_(state):
        z, gram, _, codes, rounds, steps, _, _ = state
        sol = levenberg_marquardt(_reduced_residual, z, (par, gram_factor(gram)),
                                  max_steps=max_steps, rtol=rtol, atol=atol, norm=optx.max_norm,
                                  normal_cholesky=True)
        new_codes, ssr = source_codes(sol.value, par, recordings)
        settled = jnp.all(new_codes == codes)
        # Unchanged sources, unchanged M: the Gram is only recomputed where they moved
        # (most refinements settle in their second round, which then costs one
        # play-operator pass instead of a pass and a Gram).
        new_gram = jax.lax.cond(settled, lambda: gram,
                                lambda: gram_from_codes(new_codes, par, recordings))
        return (sol.value, new_gram, ssr, new_codes, rounds + 1,
                steps + sol.stats["num_steps"], sol.result, settled)

    def again(state):
        *_, rounds, steps, result, settled = state
        return ~settled & (rounds < MAX_ROUNDS) & (result == ok) & (steps < max_steps)

    # The first round always runs (``again`` holds for this state while max_steps >= 1):
    # the round is traced once, inside the loop, not a second time before it.
    init = (z0, gram0, ssr0, codes0, jnp.asarray(0), jnp.asarray(0), ok, jnp.asarray(False))
    z, gram, ssr, _, _, steps, result, settled = jax.lax.while_loop(again, round_, init)
    in_budget = steps < max_steps
    result = optx.RESULTS.where(settled | in_budget | (result != ok),
                                result, optx.RESULTS.nonlinear_max_steps_reached)
    return z, result, steps, gram, ssr, ~settled & in_budget & (result == ok), ssr0
