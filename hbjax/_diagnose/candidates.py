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


def _ints(delay=0, time=None):
    return neutral_ints(delay) if time is None else neutral_ints(delay, time)


def build(ctx: Context, effects) -> list[Candidate]:
    """One candidate per effect class (their starts from the context's signatures), then
    the anchored variant of each (:func:`anchored`), in the same order."""
    free = [cls.candidate(ctx) for cls in effects]
    return free + [anchored(c, ctx) for c in free if c.cls.anchorable]


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


def fixed_b(lay: Layout, theta) -> int:
    """Index of the ``b`` coefficient held fixed: only ``(A, mu B, P / mu)`` is identifiable
    (paper section 4.1), so one scale is frozen (the largest ``b``) to remove the flat
    direction."""
    return int(np.argmax(np.abs(lay.base(np.asarray(theta))[1])))


def _columns(lay: Layout, free, levels, theta0, base: bool = True) -> list[np.ndarray]:
    slots = lay.slots()
    theta0 = np.asarray(theta0)  # read on the host: eager slices of a device array are slow
    held = fixed_b(lay, theta0)
    skip = {slots["b"][0] + held, slots["db"][0] + held}
    free = [(s, 1.0) for s in BASE_SLOTS] * base + list(free)
    # a clip level is freed only where the start clips (an open side stays open)
    free += [(s, 1.0) for s in levels if np.isfinite(float(lay.get(theta0, s)[0]))]
    cols = []
    for name, scale in free:
        start, stop = slots[name]
        for k in range(start, stop):
            if k in skip:
                continue
            col = np.zeros(lay.size)
            col[k] = scale
            cols.append(col)
    return cols


def selection(lay: Layout, cand: Candidate, theta0, K: int) -> np.ndarray:
    """The ``(P, K)`` matrix mapping the free parameters (base + extension) into theta."""
    cols = _columns(lay, cand.free, cand.levels, theta0, base=not cand.anchored)
    S = np.zeros((lay.size, K))
    if cols:
        S[:, :len(cols)] = np.stack(cols, 1)
    return S


def base_selection(lay: Layout, theta0, K: int) -> np.ndarray:
    """:func:`selection` of the base parameters alone (the refit)."""
    cols = _columns(lay, (), (), theta0)
    S = np.zeros((lay.size, K))
    S[:, :len(cols)] = np.stack(cols, 1)
    return S


def n_free(lay: Layout, cand: Candidate, theta) -> int:
    """Number of fitted parameters (the complexity in the information criterion)."""
    extra = 0 if cand.params is None else int(np.shape(cand.params)[-1])
    return len(_columns(lay, cand.free, cand.levels, theta, base=not cand.anchored)) + extra


def to_model(ctx: Context, cand: Candidate, theta, ints):
    """The fitted candidate as an instance of its effect class."""
    return cand.cls.from_fit(ctx, theta, ints, cand.params)
