"""The actuator limit (a clip of the internal signal ``u``) fitted on top of the nominal
model, validated over folds of the whole record where the held-out part cannot confirm it.

A filtered-noise input reaches its extremes in a few bursts; the split balances the
input's spread, not its extremes, so all of them can fall in the fitting part. The clip
then gains thousands in BIC there, while nothing held out can confirm it, and a diagnosis
that reports a mechanism only on held-out evidence names nothing. A limit acting on a few
percent of the samples at about one noise standard deviation is also below the power of
the held-out 30 % alone (z 1.2-1.8 where the fitting segment gained 1000-4700 in BIC);
the folds test it on every sample of the record. With the base held, the
clip's effect on the free run is linear in the clipped excess,
``y = y_nom + (B / A) (clip(u, lower, upper) - u)`` (eq. (10) driven by the clipped
signal), so its levels are fitted exactly and cheaply, fold by fold, with no compiled
code, as the output clip's are (:mod:`hbjax._diagnose.clip_nominal`)."""

from __future__ import annotations

import itertools
import math

import jax.numpy as jnp
import numpy as np

from .._misc import jsonable as _jsonable
from . import effects as fx
from . import residual_tests as rt
from .clip_nominal import (MIN_CHANGED, N_FOLDS, _best_level, _significant, fold_edges,
                           held_base_refusal, other_blocks)
from .decide import BIC_MARGIN, over_constant
from .effect_base import ANCHORED
from .kernel import MAX_DELAY
from .result import Finding

#: key of the candidate table for the actuator limit validated by folds
ON_NOMINAL = "input_saturation (clip of the nominal internal signal, folds)"
#: a sample counts as changed by the clip where its free run moves by more than this
#: fraction of the nominal model's free-run error spread (the clip's effect decays through
#: the linear block instead of stopping, as an output clip's does)
CHANGED_FRACTION = 0.05


def _levels(resid, u, part):
    """Clip levels ``{"lower", "upper"}`` of the internal signal minimising the sum of
    ``resid(lower, upper)[part] ** 2``; a side stays open (``-inf`` / ``inf``) unless a
    level inside the range of ``u[part]`` lowers that sum. Each side by the output clip's
    grid search (:func:`hbjax._diagnose.clip_nominal._best_level`, 201 levels from the
    median to the extreme, then 101 around the best); the upper side first, then the
    lower, then the upper again with the lower in place."""
    levels = {"lower": -np.inf, "upper": np.inf}
    mid = float(np.median(u[part]))

    def sse(lo, hi):
        return float(np.sum(resid(lo, hi)[part] ** 2))

    for side in ("upper", "lower", "upper"):
        s = 1 if side == "upper" else -1
        reach = float(np.max(s * u[part]))
        if reach <= s * mid:
            continue
        trial = dict(levels, **{side: s * np.inf})
        open_cost = sse(trial["lower"], trial["upper"])
        best = _best_level(sse, levels, side, s * mid, reach, points=201)
        trial[side] = s * best
        levels[side] = (s * best if best < reach and sse(trial["lower"], trial["upper"]) < open_cost
                        else s * np.inf)
    return levels


def input_clip_on_nominal(ctx, model, y, v, n_fit, burn, ysim_all, u_all, stats, names,
                          criterion):
    """The actuator limit fitted on the nominal model (base held) and cross-validated over
    ``N_FOLDS`` contiguous blocks of the whole record; tried only where the diagnosis found
    no mechanism (its levels on the fitting segment cost a few hundredths of a second).

    Decision (all required): BIC gain over the nominal model > BIC_MARGIN on the fitting
    segment (levels fitted there, on the diagnosis's criterion), and a BIC there no worse
    than every other effect's held on the nominal base (the anchored candidates); in the
    cross-validation, where each block's free run is clipped at levels fitted on the other
    blocks (so every clip it applies was predicted from other parts of the record), the
    clip changes at least MIN_CHANGED samples, lowers their error significantly
    (Diebold-Mariano z > DM_Z or the event sign test, as for the output clip) and lifts
    the free-run fit over the record; the refit does not simulate the held-out part
    significantly better than the nominal model (Diebold-Mariano z <= DM_Z: a base that
    must move is not explained by an actuator limit alone), and the nominal model
    simulates it significantly better than a constant output. A side of the clip reached
    in one block only cannot be predicted from the others, so it is not confirmed.

    Returns ``(table_row | None, Finding | None)``."""
    from scipy.signal import lfilter  # (imported where used: 0.85 s of `import hbjax`)

    lay = ctx.lay
    a, b = (np.asarray(x) for x in lay.base(ctx.theta_nom)[:2])
    num, den = np.r_[0.0, b], np.r_[1.0, a]
    u = np.asarray(u_all[0])
    y_nom = lfilter(num, den, u)  # the nominal free run from rest, as the kernel's
    eps_nom = lfilter(den, [1.0], y - y_nom)
    b0 = lay.na + lay.nb + MAX_DELAY + 4
    T = len(y)

    def excess(lo, hi):
        return np.clip(u, lo, hi) - u

    def free_run(lo, hi):
        return y_nom + lfilter(num, den, excess(lo, hi))

    def resid(lo, hi):
        if criterion == "prediction":  # A y - B clip(u): the equation error, a FIR filter
            return eps_nom - lfilter(num, [1.0], excess(lo, hi))
        return y - free_run(lo, hi)

    fitting = np.zeros(T, bool)
    fitting[b0:n_fit] = True
    lv = _levels(resid, u, fitting)
    lo, hi = lv["lower"], lv["upper"]
    k = int(np.isfinite(lo)) + int(np.isfinite(hi))
    if k == 0:
        return None, None
    n = n_fit - b0
    sse_nom = float(np.sum(resid(-np.inf, np.inf)[fitting] ** 2))
    sse_ext = float(np.sum(resid(lo, hi)[fitting] ** 2))
    dbic = n * math.log(max(sse_nom, 1e-300) / max(sse_ext, 1e-300)) - k * math.log(n)
    held_acts = int(np.sum(excess(lo, hi)[n_fit:] != 0))
    r_main = resid(lo, hi)[burn:n_fit]
    n_main = n_fit - burn
    bic_main = n_main * math.log(max(float(np.sum(r_main**2)), 1e-300) / n_main) \
        + k * math.log(n_main)
    row = {"bic": bic_main, "k": k, "dbic_from_burn_in": dbic, "burn_in": b0,
           "held_out_samples_clipped": held_acts,
           "lower": lo if np.isfinite(lo) else None, "upper": hi if np.isfinite(hi) else None}
    if not dbic > BIC_MARGIN:
        row["decision"] = "BIC gain on the fitting segment not above the margin"
        return row, None
    # The effects held on the nominal base compete on the fitting segment's BIC: a limit
    # that another one explains better there (a compressive sensor, an unmodelled lag)
    # is that effect's approximant, whatever the folds then say about it.
    rivals = {name[:-len(ANCHORED)]: float(stats[i + 1]["bic"]) for i, name in enumerate(names)
              if name.endswith(ANCHORED) and not name.startswith("input_saturation")}
    leader = min(rivals, key=rivals.get, default=None)
    if leader is not None and rivals[leader] < bic_main:
        row["decision"] = (f"{leader} on the nominal base explains the fitting segment "
                           f"better (BIC lower by {bic_main - rivals[leader]:.1f})")
        return row, None
    validation = _folds(y, y_nom, u, resid, free_run, b0)
    row["folds"] = validation
    ref_i = names.index("parameter_mismatch") + 1
    fit_refit, dm_refit = float(stats[ref_i]["fit_sim"]), stats[ref_i].get("dm_z", 0.0)
    dm_const = over_constant(y, n_fit, burn, y[n_fit:] - np.asarray(ysim_all[0])[n_fit:])
    row["dm_z_over_constant"] = dm_const
    why = held_base_refusal(validation, dm_refit, dm_const, "an actuator limit")
    row["decision"] = why or "reported"
    if why is not None:
        return row, None
    ext = fx.InputSaturation(model, jnp.asarray(lo) if np.isfinite(lo) else None,
                             jnp.asarray(hi) if np.isfinite(hi) else None)
    text = ext.describe(ctx, dict(y=y, v=v, n_fit=n_fit))
    evidence = {
        "variant": "actuator limit fitted on the nominal model (base parameters held fixed)",
        "validation": validation, "reference": "nominal", "base": "nominal (held)",
        "delta_bic_vs_nominal": dbic, "delta_bic_vs_refit": stats[ref_i]["bic"] - bic_main,
        "bic": bic_main, "dm_z": validation["dm_z"],
        "event_sign_test": validation["event_sign_test"],
        "held_out_samples_clipped": held_acts, "dm_z_over_constant": dm_const,
        "reference_fit": validation["fit_nominal"], "refit_fit": fit_refit,
        "parameters_fitted": k, "kind": "mechanism",
    }
    return row, Finding(
        effect="input_saturation", physics=text["physics"], where=_jsonable(text["where"]),
        parameters=_jsonable(text["parameters"]), model=ext, metric="simulation",
        fit_before=validation["fit_nominal"], fit_after=validation["fit_clip"],
        evidence=_jsonable(evidence))


def _folds(y, y_nom, u, resid, free_run, b0):
    """Cross-validation over ``N_FOLDS`` contiguous blocks from the structural burn-in
    ``b0``: each block's free run is the nominal one with the internal signal clipped at
    levels fitted on the other blocks (the clip's effect spills over a block's edge
    through the linear block; only the block's own samples are kept). See
    :func:`input_clip_on_nominal` for the acceptance rule."""
    T = len(y)
    edges = fold_edges(T, b0)
    y_cv = np.array(y_nom, dtype=float)
    fold_levels, acting = [], []
    for lo_edge, hi_edge in itertools.pairwise(edges):
        lv = _levels(resid, u, other_blocks(T, b0, lo_edge, hi_edge))
        fold_levels.append({s: (float(x) if np.isfinite(x) else None) for s, x in lv.items()})
        y_cv[lo_edge:hi_edge] = free_run(lv["lower"], lv["upper"])[lo_edge:hi_edge]
        clipped = np.clip(u[lo_edge:hi_edge], lv["lower"], lv["upper"])
        acting.append(int(np.sum(clipped != u[lo_edge:hi_edge])))
    r_nom, r_cv = (y - y_nom)[b0:], (y - y_cv)[b0:]
    changed = np.abs(y_cv - y_nom)[b0:] > CHANGED_FRACTION * (float(np.std(r_nom)) or 1.0)
    n_changed = int(changed.sum())
    dm = rt.diebold_mariano(r_nom[changed], r_cv[changed]) if n_changed >= 2 else 0.0
    sign = rt.event_sign_test(r_nom, r_cv, changed)
    fit_nom = rt.fit_percent_unchecked(y[b0:], y_nom[b0:])
    fit_cv = rt.fit_percent_unchecked(y[b0:], y_cv[b0:])
    accepted = bool(n_changed >= MIN_CHANGED and _significant(dm, sign) and fit_cv > fit_nom)
    return {"by": f"{N_FOLDS} folds of the whole record",
            "accepted": accepted, "changed": n_changed, "dm_z": float(dm),
            "event_sign_test": sign, "fit_nominal": float(fit_nom), "fit_clip": float(fit_cv),
            "clipped_samples_per_fold": acting, "fold_levels": fold_levels,
            "fold_edges": [int(e) for e in edges]}
