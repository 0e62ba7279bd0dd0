"""Records held far from zero: :func:`hbjax.fit` and :func:`hbjax.refine` solve on the
input less its midpoint and the output less its first samples' mean, and report the model in the
records' own coordinates (``refine`` maps its start onto the centred records first,
:func:`to_centred`).

- **The input.** The branches are polynomials in ``v``. Where the recorded inputs lie far
  from zero against their own spread (a valve between 40 and 60 %, a temperature around
  its set point), the powers ``v^i`` are nearly collinear over the data: the Gauss-Newton
  matrix is singular to rounding, every branch coefficient reads as unidentified and the
  starts' random bands (drawn in ``v / max|v|``) all bend near one end of the data. On
  random paper-class systems of the independent generator with the input moved by 9-18
  half-ranges, m = 5 fits were refused as ``branches_undetermined`` (one validating at
  99.97 %, another at 72 %). ``P(v) = sum_j d_j (v - c)^j`` has the coefficients
  ``sum_{j >= i} C(j, i) (-c)^(j - i) d_j`` in powers of ``v``: a fixed linear map.
- **The output.** An output offset ``ybar`` (an operating point, a sensor's zero) is in the
  model only as the branches' constant terms, ``A(1) ybar = B(1) delta``. Moved by 10^3
  times its range, the fit of a random system stopped at 1.15 times the cost of the
  unshifted records (validation 95.0 % against 98.8 %); by 10^4 its coefficients read as
  unidentified. The models ``(A, B, P)`` on ``(v, y - ybar)`` and ``(A, B, P + delta)`` on
  ``(v, y)`` give the same outputs from the same internal state, and with the initial
  state estimated the output lags before the record are left out either way; one thing
  differs: the criterion starts the play operator at ``u = 0``, which on the centred
  records is the internal value whose steady output is ``ybar`` and on the records as
  recorded a state far below or above both branches (the play then jumps onto a branch
  at the first sample). So ``ybar`` is the records' first output, where they start
  (:func:`record_centres`): exact for a record that starts at rest, and otherwise as
  near as the records tell. The output is centred only with ``initial_state="estimate"`` and only where it lies
  far from zero; the reported costs, residual tests and judgements are those of the
  centred solve, and the model's start on the records as recorded is best taken from
  :func:`hbjax.estimate_initial_state` (as :func:`hbjax.compare` does). From rest
  (``initial_state="zero"``) the records are solved as they are.

The input's centre is an exact reparametrisation. The model, its covariance (through the
map's Jacobian) and its identified flags carry over (:func:`in_recorded_coordinates`); a
parameter is unidentified where it draws on an unidentified one.
"""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._core.model import Hammerstein
from .quality import mark_unidentified

# A centre is taken out where it lies farther from zero than this many half-ranges of the
# recorded values (their range then excludes zero by at least its own width). Records that
# straddle zero, or nearly, are solved as recorded.
FAR = 2.0


def _far_centre(values, anchor=None):
    """`anchor` (default: the values' midpoint) where the midpoint lies more than
    :data:`FAR` half-ranges from zero, else 0."""
    lo = jnp.min(jnp.stack([jnp.min(x) for x in values]))
    hi = jnp.max(jnp.stack([jnp.max(x) for x in values]))
    centre, half = (hi + lo) / 2, (hi - lo) / 2
    # (a constant signal: no centre identifies anything more, and its scale would vanish)
    return jnp.where((half > 0) & (jnp.abs(centre) > FAR * half),
                     centre if anchor is None else anchor, 0.0)


def record_centres(recordings, initial_state: str):
    """``(v_centre, y_centre)`` where the recorded inputs / outputs lie more than
    :data:`FAR` half-ranges from zero, else 0: the inputs' midpoint; the mean of the
    records' *first* outputs, only with ``initial_state="estimate"`` (traceable).

    The output's centre is where the criterion's play operator starts (``u = 0`` on the
    centred records has the steady output ``y_centre``), so it is anchored at the records'
    start, not their midpoint: on a random system whose records start from rest 14 % of
    the output's range below its midpoint (two records of 220-300 samples, moved by 40
    ranges), the midpoint sent `fit` and `refine` to a model 7598 ``sigma^2`` above the
    true system's cost (517), reported as a success; anchored at the first samples they
    reach 511, the unmoved records' optimum."""
    v_centre = _far_centre([v for v, _ in recordings])
    y_centre = _far_centre([y for _, y in recordings],
                           jnp.mean(jnp.stack([y[0] for _, y in recordings])))
    return v_centre, (y_centre if initial_state == "estimate" else jnp.zeros_like(y_centre))


# fit also solves at rest at the records' first output (start_centres) where that lies
# farther than this fraction of the output's range from the centre it solved at.
ANCHOR_SHIFT = 0.05


def start_centres(recordings):
    """``(v_centre, y_centre)`` with the output's centre at the records' first outputs
    (their mean), near zero or not: the criterion's play operator then starts at rest
    there. Where a record does not start at rest at the coordinates' origin this is the
    nearer guess: on records cut from a longer run of random systems (chirps, 1000
    samples) `fit` at rest at zero validated at 87.3 and 94.0 %, at rest at the first
    output at 97.7 and 97.9 % (the truth's refinement from its estimated start: 97.9 %)."""
    v_centre, _ = record_centres(recordings, "zero")
    return v_centre, jnp.mean(jnp.stack([y[0] for _, y in recordings]))


def at_better_start(solve, recordings, centres, first):
    """`first` (a result of ``solve(centres)``, under ``initial_state="estimate"``), or
    ``solve`` at rest at the records' first output (:func:`start_centres`) where that lies
    farther than :data:`ANCHOR_SHIFT` of the output's range from `centres` and fits better
    (:func:`fits_better`). The criterion's play operator starts at rest at the output's
    centre; a record that starts elsewhere may be solved better at rest where it starts."""
    from .refine_result import fits_better  # (the results import the centring's maps)

    anchored = start_centres(recordings)
    if float(jnp.abs(anchored[1] - centres[1])) <= ANCHOR_SHIFT * output_range(recordings):
        return first
    other = solve((centres[0], anchored[1]))
    return other if fits_better(other, first) else first


def output_range(recordings) -> float:
    """The recorded outputs' range (over all records)."""
    return float(max(np.max(np.asarray(y)) for _, y in recordings)
                 - min(np.min(np.asarray(y)) for _, y in recordings))


def less_centres(recordings, v_centre, y_centre):
    """The records with the centres taken out."""
    return tuple((v - v_centre, y - y_centre) for v, y in recordings)


def recentring_matrix(centre, m: int):
    """``T`` with ``c_v = T d`` for branch coefficients ``d`` in powers of ``v - centre``
    and ``c_v`` in powers of ``v`` (ascending; the identity at ``centre = 0``)."""
    i, j = np.arange(m)[:, None], np.arange(m)[None, :]
    binomial = np.array([[math.comb(b, a) if b >= a else 0 for b in range(m)]
                         for a in range(m)], float)
    return jnp.asarray(binomial) * (-centre) ** jnp.asarray(np.maximum(j - i, 0))


def _branch_shift(a, b, y_centre):
    """``A(1) y_centre / B(1)``: how far both branches move with the output's offset."""
    gain = jnp.sum(b)
    # (no shift where the output was not moved; no NaN for a failed start with B(1) = 0,
    # whose shift means nothing)
    return jnp.where(y_centre == 0, 0.0, (1.0 + jnp.sum(a)) * y_centre
                     / jnp.where(gain == 0, 1.0, gain))


def _to_recorded(theta, v_centre, y_centre, na: int, nb: int, m: int):
    """Flattened ``[a, b, c1, c2]`` solved on the centred records -> the same model on the
    records as recorded: the branches moved by ``A(1) y_centre / B(1)`` and re-expanded in
    powers of ``v``."""
    a, b = theta[:na], theta[na:na + nb]
    delta = _branch_shift(a, b, y_centre)
    t = recentring_matrix(v_centre, m)
    c1 = t @ theta[na + nb:na + nb + m].at[0].add(delta)
    c2 = t @ theta[na + nb + m:].at[0].add(delta)
    return jnp.concatenate([a, b, c1, c2])


def to_centred(model: Hammerstein, v_centre, y_centre) -> Hammerstein:
    """`model` (coefficients in powers of ``v``, outputs as recorded) on the records less
    their centres: the inverse of the map :func:`in_recorded_coordinates` applies (the
    branches moved by ``-A(1) y_centre / B(1)``, re-expanded in powers of
    ``v - v_centre``). Traceable."""
    bl, arx = model.backlash, model.arx
    delta = _branch_shift(arx.a, arx.b, y_centre)
    t = recentring_matrix(-v_centre, bl.m)  # (powers of v -> powers of v - v_centre)
    return Hammerstein(type(bl)((t @ bl.c1).at[0].add(-delta), (t @ bl.c2).at[0].add(-delta)),
                       arx)


def refine_centres(recordings, model: Hammerstein, initial_state: str, h_m):
    """:func:`record_centres` for :func:`hbjax.refine`: the input's only in the static-gain
    gauge (``h_m=None``: the paper's gauge ``P2(-h_m) - P1(h_m) = 1`` is set at the
    recorded inputs ``+-h_m``), the output's only for a start with a static gain
    (``B(1) != 0``: the offset ``A(1) y_centre / B(1)`` is carried by the branches)."""
    v_centre, y_centre = record_centres(recordings, initial_state)
    if h_m is not None:
        v_centre = jnp.zeros_like(v_centre)
    return v_centre, jnp.where(jnp.sum(model.arx.b) == 0, 0.0, y_centre)


def in_recorded_coordinates(res, v_centre, y_centre, spread_of=None):
    """``res`` (a :class:`hbjax.FitResult` or :class:`RefineResult` solved on the records
    less their centres) on the records as recorded: coefficients, covariance
    (``J C J^T`` with ``J`` the map's Jacobian), identified flags, the input ranges and,
    for a fit, the starts' optima and their spread (``spread_of(ok, costs, params,
    best)``)."""
    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    bl = res.model.backlash
    theta_c = jnp.concatenate([res.model.arx.a, res.model.arx.b, bl.c1, bl.c2])
    to = functools.partial(_to_recorded, v_centre=v_centre, y_centre=y_centre, na=na,
                           nb=nb, m=m)
    theta = to(theta_c)
    jac = jax.jacfwd(to)(theta_c)
    model = Hammerstein(type(bl)(theta[na + nb:na + nb + m], theta[na + nb + m:]),
                        res.model.arx)
    unknown = (~res.identified).astype(jac.dtype)
    identified = (jnp.abs(jac) > 0).astype(jac.dtype) @ unknown == 0
    known = res.identified[:, None] & res.identified[None, :]
    covariance = jac @ jnp.where(known, res.covariance, 0.0) @ jac.T
    starts = {}
    if spread_of is not None:
        params = jax.vmap(to)(res.starts_params)
        ok = jnp.isfinite(res.starts_costs)
        spread, _ = spread_of(ok, res.starts_costs, params, res.best_index)
        starts = dict(starts_params=params, spread=spread)
    return dataclasses.replace(
        res, model=model, covariance=mark_unidentified(covariance, identified),
        identified=identified, active_ranges=res.active_ranges + v_centre,
        data_range=res.data_range + v_centre, **starts)
