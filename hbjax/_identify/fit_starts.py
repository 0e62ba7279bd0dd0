"""The starts of multi-start fitting: random bands, bands that close the loop inside the
data, the linear block given a band (least squares, eq. (10)), and the canonical labelling
of the branches of a fitted model (with its covariance swapped alongside).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._core.arx import ARX
from .._core.backlash import Backlash, play_sources, polyval_ascending
from .._core.model import Hammerstein
from .criteria import unpack, where_valid
from .linear import arx_least_squares


# One start in CLOSING_SHARE (the last ones) closes the best open start's loop inside the
# data (closing_band) and is solved on the core operator.
CLOSING_SHARE = 4


def random_backlash(key, m: int, scale) -> Backlash:
    """A random band in ``x = v / scale``: branches ``o -+ w + x + sum_i d_i x^i`` with
    half-gap ``w`` log-uniform in [0.02, 1] (of the input range), offset ``o`` within the
    gap and random curvature. The scale and sign of the slope need not vary: the linear
    least squares of :func:`arx_given_backlash` absorbs them into ``b``."""
    k_w, k_o, k_d, k_e = jax.random.split(key, 4)
    w = jnp.exp(jax.random.uniform(k_w, minval=jnp.log(0.02), maxval=0.0))
    o = jax.random.uniform(k_o, minval=-0.5, maxval=0.5) * w
    base = jnp.zeros(m).at[0].set(o)
    if m > 1:
        base = base.at[1].set(1.0)
    if m > 2:
        base = base.at[2:].set(0.3 * jax.random.normal(k_d, (m - 2,)))
    tilt = jnp.zeros(m)
    if m > 1:
        tilt = tilt.at[1:].set(0.1 * w * jax.random.normal(k_e, (m - 1,)))
    powers = scale ** jnp.arange(m)
    c1 = (base - tilt).at[0].add(-w) / powers
    c2 = (base + tilt).at[0].add(w) / powers
    return Backlash(c1, c2)


def closing_positions(count: int) -> np.ndarray:
    """Where (in ``v / scale``) :func:`closing_band` closes the loop for `fit`'s `count`
    closing starts: spread over ``+-[0.2, 0.95]``, alternately on both sides."""
    half = max(-(-count // 2), 1)
    where = np.linspace(0.2, 0.95, half) if half > 1 else np.array([0.6])
    return np.stack([where, -where], axis=1).ravel()[:count]


def closing_band(model: Hammerstein, scale, x0) -> Backlash:
    """A band that keeps ``model``'s mean branch ``(P1 + P2) / 2`` and closes it inside the
    data: the half-gap becomes linear, zero at ``v0 = x0 scale`` and equal to the model's
    half-gap at the far end of the input range ``+-scale`` (its mean absolute half-gap if
    that is not positive). A start for a loop that closes inside the data, which a solve
    from an open band does not reach (:func:`fit_traceable`)."""
    bl = model.backlash
    m = bl.c1.shape[0]
    mean, gap = (bl.c1 + bl.c2) / 2, (bl.c2 - bl.c1) / 2
    v0 = x0 * scale
    end = -jnp.sign(x0) * scale  # the open side
    g = polyval_ascending(gap, end)
    g = jnp.where(g > 0, g, jnp.mean(jnp.abs(polyval_ascending(
        gap, jnp.linspace(-1.0, 1.0, 33) * scale))))
    slope = g / (end - v0)
    h = jnp.zeros(m, mean.dtype).at[0].set(-slope * v0).at[1].set(slope)
    return Backlash(mean - h, mean + h)


def arx_given_backlash(backlash: Backlash, recordings, na: int, nb: int,
                       skip: int = 0) -> ARX:
    """Least-squares ``a, b`` of the equation-error regression (eq. (10)) with
    ``u = HB(v)`` known: linear in ``a, b``, solved over all records at once (leaving out
    each record's first `skip` samples)."""
    def internal(v):
        # the core operator (sorted band): the random starts' branches may cross
        p1, p2 = backlash.p1(v), backlash.p2(v)
        return play_sources(jnp.minimum(p1, p2), jnp.maximum(p1, p2))[0]

    theta = arx_least_squares([(internal(v), y, mask)
                               for v, y, mask in map(unpack, recordings)], na, nb, skip=skip)
    return ARX(theta[:na], theta[na:])


def canonical_labels(model: Hammerstein, recordings) -> tuple[Hammerstein, Array]:
    """Swap ``c1``/``c2`` so that ``P1`` is the branch a rising input drives the output
    onto: the lower one when the band rises with ``v``, the upper one when it falls
    (``L = min``, ``H = max`` make the labels otherwise interchangeable)."""
    bl = model.backlash
    records = [unpack(rec) for rec in recordings]
    lo = jnp.min(jnp.stack([jnp.min(where_valid(mask, v, jnp.inf)) for v, _, mask in records]))
    hi = jnp.max(jnp.stack([jnp.max(where_valid(mask, v, -jnp.inf)) for v, _, mask in records]))
    rising = (bl.p1(hi) + bl.p2(hi)) >= (bl.p1(lo) + bl.p2(lo))
    # (the sign of the mean gap over the recorded samples: the sum's sign is the mean's)
    p1_above = sum(jnp.sum(where_valid(mask, bl.p1(v) - bl.p2(v), 0.0))
                   for v, _, mask in records) > 0
    swap = rising == p1_above
    c1 = jnp.where(swap, bl.c2, bl.c1)
    c2 = jnp.where(swap, bl.c1, bl.c2)
    return Hammerstein(Backlash(c1, c2), model.arx), swap


def canonical_result(res, recordings):
    """``res`` (a :class:`hbjax.RefineResult` or :class:`hbjax.FitResult`) with the labels
    of :func:`canonical_labels`, and what follows the labels swapped alongside: the
    covariance, the identified flags and the branches' active ranges. Traceable."""
    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    model, swap = canonical_labels(res.model, recordings)
    return eqx.tree_at(
        lambda r: (r.model, r.covariance, r.identified, r.active_ranges), res,
        (model, swap_covariance(res.covariance, swap, na, nb, m),
         jnp.where(swap, res.identified[swap_perm(na, nb, m)], res.identified),
         jnp.where(swap, res.active_ranges[::-1], res.active_ranges)))


def swap_perm(na, nb, m):
    off = na + nb
    perm = np.arange(off + 2 * m)
    perm[off:off + m], perm[off + m:] = np.arange(off + m, off + 2 * m), np.arange(off, off + m)
    return perm


def swap_covariance(cov, swap, na, nb, m):
    perm = swap_perm(na, nb, m)
    swapped = cov[perm][:, perm]
    return jnp.where(swap, swapped, cov)


def closing_count(starts: int, m: int) -> int:
    """How many of `fit`'s starts are closing bands (:func:`closing_bands`): every
    :data:`CLOSING_SHARE`-th start (none for constant branches, ``m = 1``)."""
    return starts // CLOSING_SHARE if m > 1 else 0
