"""Fitting every candidate of a diagnosis: choose each start by a batched evaluation of
the criterion, fit the kernel effects in three compiled batches of fixed size (shared by
every call with the same base structure and record length) and the generic effects one by
one, then evaluate all of them over the whole record."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from . import candidates as cands
from .effect_base import Context
from .effects import EFFECTS
from .kernel_effect import AbstractKernelEffect
from .solve import evaluate_batch, evaluate_terms, fit_batch, fit_terms, sse_batch, sse_terms

_SSE_BATCH = 64


def _batched_sse(lay, thetas, ints, consts, v, y, burn, criterion):
    out = []
    for i in range(0, len(thetas), _SSE_BATCH):
        th, it = thetas[i:i + _SSE_BATCH], ints[i:i + _SSE_BATCH]
        pad = _SSE_BATCH - len(th)
        vals = sse_batch(lay, jnp.stack(th + th[:1] * pad),
                         jnp.asarray(np.stack(it + it[:1] * pad)), consts, v, y, burn, criterion)
        out.extend(np.asarray(vals)[:len(th)].tolist())
    return [v if math.isfinite(v) else np.inf for v in out]


def choose_starts(ctx: Context, candidates, v, y, criterion):
    """The best start ``(theta0, ints)`` of each candidate (lowest criterion); a generic
    candidate keeps its best parameter start in ``params``."""
    lay = ctx.lay
    starts = [(ci, th, it) for ci, c in enumerate(candidates) for th, it in c.starts]
    sse = _batched_sse(lay, [s[1] for s in starts], [s[2] for s in starts], ctx.consts, v, y,
                       ctx.burn, criterion)
    chosen = {}
    for (ci, th, it), val in zip(starts, sse):
        if ci not in chosen or val < chosen[ci][0]:
            chosen[ci] = (val, th, it)
    for ci, c in enumerate(candidates):
        if c.generic:
            vals = np.asarray(sse_terms(c.cls, lay, chosen[ci][1], jnp.asarray(c.params),
                                        ctx.consts, v, y, ctx.burn, criterion))
            vals = np.where(np.isfinite(vals), vals, np.inf)
            c.params = np.asarray(c.params)[int(np.argmin(vals))]
    return ([chosen[i][1] for i in range(len(candidates))],
            [chosen[i][2] for i in range(len(candidates))])


def _group(cls):
    """Compiled batch of a kernel effect: output clip/curvature, change model, others."""
    return (cls.output_static, cls.wide)


_GROUPS = ((True, False), (False, True), (False, False))


def _variants(cls, kernel_only: bool = False) -> int:
    """Candidates an effect class gives: itself and, if anchorable, its anchored variant
    (``kernel_only``: those of them fitted in the kernel's batches)."""
    anchored = cls.anchorable and not (kernel_only and cls.anchored_form is not None
                                       and not issubclass(cls.anchored_form,
                                                          AbstractKernelEffect))
    return 1 + bool(anchored)


def fit_candidates(ctx: Context, candidates, theta0, ints, v, y, criterion, max_steps):
    """Fit every candidate: jointly with the base parameters, or, for an anchored one,
    with the base held at the nominal values (its selection has no base columns).
    Returns ``(theta (n, P), steps (n,), converged (n,))``; generic candidates' fitted
    parameters go to ``candidate.params``."""
    lay, consts, burn = ctx.lay, ctx.consts, ctx.burn
    n = len(candidates)
    theta_fit = [None] * n
    steps, ok = np.zeros(n, int), np.zeros(n, bool)
    kernel = [issubclass(c.cls, AbstractKernelEffect) and not c.generic for c in candidates]
    for group in _GROUPS:
        idx = [i for i, c in enumerate(candidates) if kernel[i] and _group(c.cls) == group]
        if not idx:
            continue
        size = sum(_variants(cls, kernel_only=True) for cls in EFFECTS.values()
                   if issubclass(cls, AbstractKernelEffect) and _group(cls) == group)
        K = 2 * lay.p_base if group[1] else lay.p_base + 4
        th = [theta0[i] for i in idx]
        it = [ints[i] for i in idx]
        S = [cands.selection(lay, candidates[i], theta0[i], K) for i in idx]
        pad = max(size - len(idx), 0)
        out, st, cv = fit_batch(
            lay, jnp.stack(th + th[:1] * pad), jnp.asarray(np.stack(S + S[:1] * pad)),
            jnp.asarray(np.stack(it + it[:1] * pad)), consts, v, y, burn, max_steps,
            group[0], criterion)
        for j, i in enumerate(idx):
            theta_fit[i], steps[i], ok[i] = out[j], int(st[j]), bool(cv[j])
    for i, c in enumerate(candidates):
        if kernel[i]:
            continue
        S = cands.base_selection(lay, theta0[i], lay.p_base, c.directions) * (not c.anchored)
        th, params, st, cv = fit_terms(
            c.cls, lay, jnp.asarray(theta0[i]), jnp.asarray(S), jnp.asarray(c.params),
            jnp.asarray(c.scales), consts, v, y, burn, max_steps, criterion)
        theta_fit[i], steps[i], ok[i] = th, int(st), bool(cv)
        c.params = np.asarray(params)
    return jnp.stack(theta_fit), steps, ok


def evaluate_candidates(ctx: Context, candidates, theta_fit, all_ints, v, y, criterion):
    """``(fitting error, exact prediction error, y_sim, u)`` over the whole record for the
    nominal model (row 0) and every fitted candidate."""
    lay = ctx.lay
    rows = [0] + [i + 1 for i, c in enumerate(candidates) if not c.generic]
    all_theta = jnp.concatenate([ctx.theta_nom[None], theta_fit])[np.asarray(rows)]
    its = jnp.asarray(all_ints)[np.asarray(rows)]
    # fixed batch: one compiled evaluation
    pad = max(sum(_variants(cls) for cls in EFFECTS.values()) + 1 - len(rows), 0)
    out = [np.asarray(a)[:len(rows)] for a in evaluate_batch(
        lay, jnp.concatenate([all_theta, jnp.repeat(all_theta[:1], pad, 0)]),
        jnp.concatenate([its, jnp.repeat(its[:1], pad, 0)]), ctx.consts, v, y, criterion)]
    full = [np.zeros((len(candidates) + 1,) + a.shape[1:], a.dtype) for a in out]
    for j, r in enumerate(rows):
        for f, a in zip(full, out):
            f[r] = a[j]
    for i, c in enumerate(candidates):
        if c.generic:
            got = evaluate_terms(c.cls, lay, theta_fit[i], jnp.asarray(c.params), ctx.consts,
                                 v, y, criterion)
            for f, a in zip(full, got):
                f[i + 1] = np.asarray(a)
    return tuple(full)
