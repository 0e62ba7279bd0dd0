"""Candidates of the diagnosis: each effect class gives its starts and freed slots from the
residual signatures (``cls.candidate(ctx)``); here they become the selection matrices of
the compiled solver, the complexity counted by the information criterion, and fitted
vectors become effect instances (``cls.from_fit``).

Every kernel effect is expressed in the extended parameter vector of
:mod:`hbjax._diagnose.kernel`; a candidate's selection matrix has one column per free
parameter (base and extension), scaled so that Levenberg-Marquardt sees well-conditioned
columns.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .effect_base import Candidate as Candidate, Context as Context, base_model as base_model
from .effect_base import neutral_ints
from .kernel import Layout

BASE_SLOTS = ("a", "b", "c1", "c2")
#: a branch's coefficient direction is fitted only where the fitting segment sees at least
#: this fraction of the mean square the direction has over the whole record's inputs
#: (:func:`branch_directions`)
SEEN_FRACTION = 1e-2


def _ints(delay=0, time=None):
    return neutral_ints(delay) if time is None else neutral_ints(delay, time)


def build(ctx: Context, effects) -> list[Candidate]:
    """One candidate per effect class (their starts from the context's signatures), then
    the anchored variant of each (:func:`anchored`), in the same order."""
    free = [cls.candidate(ctx) for cls in effects]
    out = free + [anchored(c, ctx) for c in free if c.cls.anchorable]
    if ctx.v_record is not None:
        seen = {}  # by the first sample a branch term acts from

        def directions(start):
            if start not in seen:
                seen[start] = branch_directions(ctx.lay, ctx.theta_nom, ctx.v_fit, ctx.u_nom,
                                                ctx.v_record, start=start)
            return seen[start]

        for c in out:  # (an anchored candidate frees no base slot: only its own apply)
            c.directions = dict(directions(ctx.burn))
            if any(name in ("dc1", "dc2") for name, _ in c.free):
                # a change's branch terms act from its start time on (the first start's)
                after = directions(max(ctx.burn, int(np.asarray(c.starts[0][1])[1])))
                c.directions.update(dc1=after["c1"], dc2=after["c2"])
    return out


def anchored(cand: Candidate, ctx: Context) -> Candidate:
    """The variant of ``cand`` that holds the base parameters at the nominal values and
    fits only the effect's own parameters (in the class's ``anchored_form`` where it has
    one).

    Why both variants: where the nominal model is right apart from the effect, a joint
    refit of the base parameters absorbs much of a weak effect within the range the record
    excites (the refit ``parameter_mismatch`` then explains the fitting segment almost as
    well, and the extension adds little to it), while the effect alone, on the nominal
    base, explains it with a handful of parameters. The two variants are ranked by the
    same information criterion."""
    if cand.cls.anchored_form is not None:
        return dataclasses.replace(cand.cls.anchored_form.candidate(ctx), anchored=True)
    return dataclasses.replace(cand, anchored=True, starts=list(cand.starts),
                               params=None if cand.params is None else np.array(cand.params))


def branch_directions(lay: Layout, theta, v_fit, u_fit, v_all, start: int = 0) -> dict:
    """The directions of each branch's coefficients (``{"c1": D1, "c2": D2}``, ``D`` of
    shape ``(m, r)``, or ``None`` where every direction is seen) that the fitting segment
    ``v_fit[start:]`` determines.

    A branch decides the output only where the play sits on it (eq. (1)); a refit of its
    coefficients from samples where it is active on a narrow band of inputs fixes its value
    there and leaves its slope and curvature to extrapolation: a plateau record whose
    falling branch was active only at inputs -2.39 to -2.33 moved that branch's
    coefficients by 2 units at no cost on the fitting segment, and its held-out free run
    fell from 92 % to 53 % where the held-out input put the play on it elsewhere. So a
    change ``delta`` of the branch is fitted only along the generalised eigenvectors of
    ``(mean over its active samples of (V delta)^2, mean over every recorded input of
    (V delta)^2)`` (``V`` the powers of eq. (1)) whose ratio is at least
    :data:`SEEN_FRACTION`; the others stay at the nominal values, and the information
    criterion counts only the fitted directions. ``u_fit`` is the nominal model's play
    output on the fitting segment, which tells where each branch is active. A record of
    fewer input levels than coefficients cannot tell the directions apart (its own mean
    square is singular): there every direction is fitted."""
    from scipy.linalg import eigh  # (imported where used, as scipy elsewhere here)

    _, _, c1, c2 = (np.asarray(x) for x in lay.base(np.asarray(theta)))
    v_fit, u_fit = np.asarray(v_fit, float)[start:], np.asarray(u_fit, float)[start:]
    powers = np.vander(np.asarray(v_all, float), lay.m, increasing=True)
    gram_all = powers.T @ powers / len(powers)
    if np.linalg.matrix_rank(gram_all) < lay.m:
        # too few input levels to tell the directions apart (a PRBS-like record of two
        # levels and m = 3): every direction is fitted, as the branches' only record
        return {"c1": None, "c2": None}
    out = {}
    tol = 1e-9 * (float(np.ptp(u_fit)) + float(np.max(np.abs(u_fit), initial=0.0)) + 1e-300)
    local = np.vander(v_fit, lay.m, increasing=True)
    for name, c in (("c1", c1), ("c2", c2)):
        on = np.abs(local @ c - u_fit) <= tol
        seen = local[on]
        gram = seen.T @ seen / max(len(seen), 1)
        try:
            ratio, vecs = eigh(gram, gram_all)
        except np.linalg.LinAlgError:  # singular in rounding only (two levels, m = 3)
            return {"c1": None, "c2": None}
        keep = ratio >= SEEN_FRACTION
        if keep.all():
            out[name] = None
            continue
        dirs = vecs[:, keep]
        out[name] = dirs / np.linalg.norm(dirs, axis=0, keepdims=True) if keep.any() \
            else np.zeros((lay.m, 0))
    return out


def fixed_b(lay: Layout, theta) -> int:
    """Index of the ``b`` coefficient held fixed: only ``(A, mu B, P / mu)`` is identifiable
    (paper section 4.1), so one scale is frozen (the largest ``b``) to remove the flat
    direction."""
    return int(np.argmax(np.abs(lay.base(np.asarray(theta))[1])))


def _columns(lay: Layout, free, levels, theta0, base: bool = True,
             directions=None) -> list[np.ndarray]:
    slots = lay.slots()
    directions = directions or {}
    theta0 = np.asarray(theta0)  # read on the host: eager slices of a device array are slow
    held = fixed_b(lay, theta0)
    skip = {slots["b"][0] + held, slots["db"][0] + held}
    free = [(s, 1.0) for s in BASE_SLOTS] * base + list(free)
    # a clip level is freed only where the start clips (an open side stays open)
    free += [(s, 1.0) for s in levels if np.isfinite(float(lay.get(theta0, s)[0]))]
    cols = []
    for name, scale in free:
        start, stop = slots[name]
        if directions.get(name) is not None:  # a branch seen only in part (branch_directions)
            for d in directions[name].T:
                col = np.zeros(lay.size)
                col[start:stop] = scale * d
                cols.append(col)
            continue
        for k in range(start, stop):
            if k in skip:
                continue
            col = np.zeros(lay.size)
            col[k] = scale
            cols.append(col)
    return cols


def selection(lay: Layout, cand: Candidate, theta0, K: int) -> np.ndarray:
    """The ``(P, K)`` matrix mapping the free parameters (base + extension) into theta."""
    cols = _columns(lay, cand.free, cand.levels, theta0, base=not cand.anchored,
                    directions=cand.directions)
    S = np.zeros((lay.size, K))
    if cols:
        S[:, :len(cols)] = np.stack(cols, 1)
    return S


def base_selection(lay: Layout, theta0, K: int, directions=None) -> np.ndarray:
    """:func:`selection` of the base parameters alone (the refit)."""
    cols = _columns(lay, (), (), theta0, directions=directions)
    S = np.zeros((lay.size, K))
    S[:, :len(cols)] = np.stack(cols, 1)
    return S


def n_free(lay: Layout, cand: Candidate, theta) -> int:
    """Number of fitted parameters (the complexity in the information criterion)."""
    extra = 0 if cand.params is None else int(np.shape(cand.params)[-1])
    return len(_columns(lay, cand.free, cand.levels, theta, base=not cand.anchored,
                        directions=cand.directions)) + extra


def to_model(ctx: Context, cand: Candidate, theta, ints):
    """The fitted candidate as an instance of its effect class."""
    return cand.cls.from_fit(ctx, theta, ints, cand.params)
