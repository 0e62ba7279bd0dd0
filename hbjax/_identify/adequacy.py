"""What a result may call a success where its free-run fit cannot judge: residual tests,
traceable, run inside every refinement (:func:`hbjax._identify.refine_result.finish`).

**No input effect.** A model with poles near 1 fitted to an output *unrelated* to the input
(a random walk, slow AR noise) integrates the input into another random walk, and the two
can agree by chance (spurious regression): a free-run fit above the floor proves nothing
then. :func:`input_effect_p` (prediction criterion) and :func:`simulated_input_effect_p`
(simulation criterion) test whether the model predicts the output better than the
output's own past.

**A fit below the floor that the noise explains.** For the paper's equation-error model
(eq. (10)), ``A(q^-1) y = B(q^-1) u + xi``, the free run ``y_sim`` of a model solves
``A y_sim = B u``, so its free-run error is exactly the one-step prediction error
integrated by the model's own ``1/A``: ``y - y_sim = e / A(q^-1)``. Where ``A(1)`` is small
(poles near 1) white equation noise reaches the output amplified by ``1/A(1)`` at low
frequency, and even the *true* system simulates worse than the record's mean: a free-run
fit below 0 % is then no evidence of a bad model. What is evidence is the residual
analysis (MATLAB's ``resid``, Ljung's validation tests, :func:`whiteness_p`): a model whose
prediction errors are white (A6), independent of past inputs, and whose input path is
significant, has extracted what the records hold about the system.

Everything here is traceable (jit/vmap) and never raises on values; the NumPy report of
the same tests for one record is :func:`hbjax.resid`.
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._core.arx import all_pole
from .._misc import chi2_sf, lag_sum
from .criteria import unpack

#: Lags of the whiteness and independence tests (MATLAB ``resid``'s default).
LAGS = 25
#: Own-past lags of the output-error fit's input test: enough to whiten the output's own
#: dynamics, so that an independent, slowly varying regressor cannot look significant.
OWN_LAGS = 10
#: Relative size (in machine epsilons) of the rounding errors of a one-step prediction or a
#: least-squares fit: below ``ROUNDING eps`` times the output's centred sum of squares a
#: sum of squared errors is taken as rounding, not noise (:func:`_rounding`).
ROUNDING = 1e3
#: Level of each test: a result whose input effect is not significant at it is refused; a
#: free-run fit below the floor is accepted as the noise's only when whiteness and
#: independence are not rejected at it.
LEVEL = 0.01


def _correlations(x, z, lags: int):
    """``sum_t x(t) z(t-k)`` for ``k = 0..lags`` (zero-filled signals of one length). A
    ``lax.map`` over the lags rather than ``lags + 1`` unrolled slices: one small loop in
    the compiled refinement instead of a hundred operations to compile."""
    t = jnp.arange(x.shape[0])

    def at(k):
        return jnp.sum(jnp.where(t >= k, x * jnp.roll(z, k), 0.0))

    return jax.lax.map(at, jnp.arange(lags + 1))


def _one_step(model, v, y, u, mask):
    """The one-step prediction errors ``e = A(q^-1) y - B(q^-1) u`` of a record (zero
    outside the samples used: the first ``max(na, nb)`` depend on the unknown past),
    the mask of the samples used and their number."""
    skip = max(model.arx.na, model.arx.nb)
    valid = jnp.arange(v.shape[0]) >= skip
    valid = valid if mask is None else valid & mask
    e = jnp.where(valid, y + lag_sum(model.arx.a, y) - lag_sum(model.arx.b, u), 0.0)
    return e, valid, jnp.sum(valid).astype(y.dtype)


def _errors(model, v, y, u, mask):
    """``(ssr, ssr_ar, n, spread)`` of one record over the samples ``t >= max(na, nb)``
    (recorded samples only): the model's squared one-step error ``sum e^2``,
    ``e = A(q^-1) y - B(q^-1) u``; that of the best linear predictor of ``y`` on its own
    ``na`` past values and a constant (from the moments ``Z^T Z`` of the rows
    ``[y(t), y(t-1..na), 1]``, no factorisation of the N-row regression); the number of
    rows; the centred sum of squares of ``y`` over them."""
    na, nb = model.arx.na, model.arx.nb
    skip, T = max(na, nb), y.shape[0]
    rows = jnp.arange(T) >= skip
    rows = rows if mask is None else rows & mask
    e = y + lag_sum(model.arx.a, y) - lag_sum(model.arx.b, u)
    ssr = jnp.sum(jnp.where(rows, e, 0.0) ** 2)
    z = jnp.stack([y[skip - i:T - i] for i in range(na + 1)] + [jnp.ones(T - skip, y.dtype)],
                  axis=1) * rows[skip:, None].astype(y.dtype)
    moments = z.T @ z
    n = moments[-1, -1]
    s = moments[:na + 1, -1]
    c = moments[:na + 1, :na + 1] - jnp.outer(s, s) / jnp.maximum(n, 1.0)  # centred
    if na == 0:
        return ssr, c[0, 0], n, c[0, 0]
    coef = jnp.linalg.lstsq(c[1:, 1:], c[1:, 0])[0]
    return ssr, jnp.maximum(c[0, 0] - c[1:, 0] @ coef, 0.0), n, c[0, 0]


def _rounding(spread, dtype):
    """The part of a sum of squared errors that rounding alone can leave: ``ROUNDING eps``
    times the output's centred sum of squares ``spread`` (the least squares here run on
    moments, whose cancellation loses digits relative to ``spread``, not to the error).

    An output that its own past predicts to rounding (noise-free, e.g. a decaying
    exponential or a sine unrelated to the input) leaves both squared errors of a test at
    this level and ``sigma^2`` with them: a drop measured in such a ``sigma^2`` is a ratio
    of two rounding errors, which can be astronomically "significant". Drops and
    ``sigma^2`` are therefore taken beyond this level."""
    return ROUNDING * jnp.finfo(dtype).eps * spread


def _lagged_gram(v_c, valid, lags: int):
    """``G[j, k] = sum_t x_j(t) x_k(t)`` of the lagged inputs ``x_k(t) = v_c(t - k)`` over
    the counted errors (``valid``, one run of samples; ``v_c`` zero outside it and before
    its start), without the ``(T, lags + 1)`` matrix of windows: for ``k = j + d``,
    ``G[j, k]`` sums ``p_d(s) = v_c(s) v_c(s - d)`` over ``s < end - j`` (``end`` one past
    the last counted error), one cumulative sum per lag difference ``d`` (the matrix of
    windows took 7 times the memory of the record under ``vmap``)."""
    size = v_c.shape[0]
    t = jnp.arange(size)
    end = jnp.max(jnp.where(valid, t + 1, 0))
    j = jnp.arange(lags + 1)

    def diagonal(d):
        c = jnp.cumsum(jnp.where(t >= d, v_c * jnp.roll(v_c, d), 0.0))
        at = end - j - 1
        return jnp.where((at >= 0) & (j + d <= lags), c[jnp.clip(at, 0, size - 1)], 0.0)

    diagonals = jax.lax.map(diagonal, j)  # [d, j] = G[j, j + d]
    return diagonals[jnp.abs(j[:, None] - j[None, :]), jnp.minimum(j[:, None], j[None, :])]


def _centred(e, valid, n):
    """``e`` less its mean over the ``valid`` samples (``n`` of them), zero elsewhere."""
    return jnp.where(valid, e - jnp.sum(jnp.where(valid, e, 0.0)) / n, 0.0)


def _ljung_box(e_c, n, lags: int):
    """Ljung-Box statistic ``N (N+2) sum_k r_e(k)^2 / (N-k)`` of centred errors ``e_c``."""
    see = jnp.maximum(jnp.sum(e_c**2), jnp.finfo(e_c.dtype).tiny)
    r_e = _correlations(e_c, e_c, lags)[1:] / see
    return n * (n + 2) * jnp.sum(r_e**2 / (n - jnp.arange(1, lags + 1)))


def _whiteness(e, v, valid, n, lags: int):
    """``(ljung_box, independence, dof)`` of one record's errors ``e``."""
    e_c = _centred(e, valid, n)
    v_c = _centred(v, valid, n)
    tiny = jnp.finfo(e.dtype).tiny
    see = jnp.maximum(jnp.sum(e_c**2), tiny)
    svv = jnp.maximum(jnp.sum(v_c**2), tiny)
    ljung_box = _ljung_box(e_c, n, lags)
    # Cross-correlations with a coloured input are correlated through the Gram matrix R_v of
    # its lagged windows: N r^T R_v^+ r is chi-square with rank(R_v) degrees of freedom (as
    # hbjax.resid; the Toeplitz matrix of v's autocorrelation stands for R_v only where it
    # is well conditioned, and made the test blind under a multisine).
    r_ev = _correlations(e_c, v_c, lags) / jnp.sqrt(see * svv)
    w, vec = jnp.linalg.eigh(_lagged_gram(v_c, valid, lags) / svv)
    keep = w > 1e-8 * jnp.max(w)
    z = vec.T @ r_ev
    independence = n * jnp.sum(jnp.where(keep, z**2 / jnp.where(keep, w, 1.0), 0.0))
    return ljung_box, independence, jnp.sum(keep)


def input_effect_p(model, recordings, sources, free: int) -> Float[Array, ""]:
    """p-value, all records pooled, of *no input effect*: the drop in squared one-step
    error from the best linear predictor on the output's own ``na`` past values and a
    constant (per record) to the model's, over ``sigma^2 = SSR / (N - free)``, against the
    chi-square distribution with the input path's parameter count ``nb + 2m - 1``. Small:
    the input explains the output. Large: the output is described as well by its own past
    (e.g. a random walk fitted with poles near 1, whose free run can still beat the
    record's mean by chance).

    ``sources``: the play operator's output of each record (core operator), as
    :func:`hbjax._identify.quality.simulation_fit` computed it; ``free``: the number of
    free parameters."""
    ssr = ssr_ar = n = spread = 0.0
    for (v, y, mask), u in zip(map(unpack, recordings), sources):
        one, ar, count, centred = _errors(model, v, y, u, mask)
        ssr, ssr_ar, n, spread = ssr + one, ssr_ar + ar, n + count, spread + centred
    rounding = _rounding(spread, ssr.dtype)
    sigma2 = jnp.maximum(ssr, rounding) / jnp.maximum(n - free, 1.0)
    drop = jnp.maximum(ssr_ar - ssr - rounding, 0.0) / jnp.maximum(sigma2, jnp.finfo(ssr.dtype).tiny)
    p = chi2_sf(drop, model.arx.nb + 2 * model.backlash.m - 1)
    return jnp.where(jnp.isfinite(p), p, jnp.nan)


def simulated_input_effect_p(model, recordings, sources, free: int, lags: int = OWN_LAGS):
    """p-value, all records pooled, of *no input effect* for an output-error fit (whose
    one-step errors are not what it minimised): does the model's free run
    ``y_sim = B/A u`` (from rest) predict ``y(t)`` beyond the output's own past? Per
    record, ``y(t)`` is regressed by least squares on ``y(t-1..lags)`` and a constant, then
    also on ``y_sim(t), ..., y_sim(t-lags)``; the drop in squared error over the larger
    regression's ``sigma^2`` is chi-square with ``lags + 1`` degrees of freedom per record
    (a Granger-type test: the output's own past is a full noise model, so a free run fitted
    by chance to a slowly wandering output unrelated to the input adds nothing to it). The
    ``free`` parameters fitted to ``y`` are added to the degrees of freedom."""
    drop = ssr1 = n = spread = 0.0
    for (v, y, mask), u in zip(map(unpack, recordings), sources):
        y_sim = all_pole(model.arx.a, lag_sum(model.arx.b, u))
        T = y.shape[0]
        rows = jnp.ones(T - lags, y.dtype) if mask is None else mask[lags:].astype(y.dtype)
        own = jnp.stack([y[lags - i:T - i] for i in range(1, lags + 1)]
                        + [jnp.ones(T - lags, y.dtype)], axis=1) * rows[:, None]
        sim = jnp.stack([y_sim[lags - i:T - i] for i in range(lags + 1)], axis=1) * rows[:, None]
        target = y[lags:] * rows
        full = jnp.concatenate([own, sim], axis=1)
        # Least squares on the rows themselves (not normal equations): lagged smooth
        # signals are nearly collinear.
        r0 = target - own @ jnp.linalg.lstsq(own, target)[0]
        r1 = target - full @ jnp.linalg.lstsq(full, target)[0]
        s0, s1 = jnp.sum(r0**2), jnp.sum(r1**2)
        centred = jnp.sum(jnp.where(rows > 0, target - jnp.sum(target) / jnp.sum(rows), 0.0) ** 2)
        drop, ssr1, n = drop + jnp.maximum(s0 - s1, 0.0), ssr1 + s1, n + jnp.sum(rows)
        spread = spread + centred
    params = len(recordings) * (2 * lags + 2)
    rounding = _rounding(spread, ssr1.dtype)
    sigma2 = jnp.maximum(ssr1, rounding) / jnp.maximum(n - params, 1.0)
    drop = jnp.maximum(drop - rounding, 0.0)
    # y_sim was itself fitted to y: its ``free`` parameters add their own chance agreement.
    p = chi2_sf(drop / jnp.maximum(sigma2, jnp.finfo(ssr1.dtype).tiny),
                len(recordings) * (lags + 1) + free)
    return jnp.where(jnp.isfinite(p), p, jnp.nan)


def whiteness_p(model, recordings, sources, lags: int = LAGS) -> Float[Array, " 2"]:
    """p-values, all records pooled, of the one-step prediction errors' whiteness
    (Ljung-Box, ``lags`` degrees of freedom per record) and of their independence from
    past inputs ``v(t-k)``, ``k = 0..lags`` (``N r^T R_v^+ r``), as :func:`hbjax.resid`.
    For a model fitted on the records both are slightly conservative."""
    lb = ind = dof = 0.0
    for (v, y, mask), u in zip(map(unpack, recordings), sources):
        e, valid, n = _one_step(model, v, y, u, mask)
        q, stat, rank = _whiteness(e, v, valid, n, lags)
        lb, ind, dof = lb + q, ind + stat, dof + rank
    p = jnp.stack([chi2_sf(lb, lags * len(recordings)), chi2_sf(ind, dof)])
    return jnp.where(jnp.isfinite(p), p, jnp.nan)


def noise_explains(p_values) -> Array:
    """Whether residual tests ``p_values`` (``[whiteness, independence, no input effect]``)
    say the records hold nothing more about the system than the model: white errors,
    independent of the input, and a significant input path (NaN: not computed)."""
    white, independent, no_input = p_values[0], p_values[1], p_values[2]
    return (white >= LEVEL) & (independent >= LEVEL) & (no_input < LEVEL)
