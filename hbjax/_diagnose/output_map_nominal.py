"""The sensor curvature (a static map of the linear block's output) fitted on top of the
nominal model, validated over folds of the whole record where the held-out part cannot
confirm it.

A static map is seen only over the output levels a part of the record holds. A filtered
noise input can leave the held-out part quiet (held-out free run within a fifth of the
fitting segment's range, where the curvature is a straight line) or put it at levels the
fitting segment never reached (a cubic extrapolated): on either, the held-out part cannot
confirm a curvature that gained hundreds in BIC on the fitting segment with its base
consistent. With the base held, the map acts on the nominal free run sample by sample,
``y = y_nom + scale (k2 z^2 + k3 z^3)``, ``z = (y_nom - center) / scale``
(:class:`hbjax._diagnose.effects.OutputNonlinearity`), so it is fitted exactly and cheaply
(linear least squares in ``k2, k3`` on a grid of centres), fold by fold, with no compiled
code, as the clips are (:mod:`hbjax._diagnose.clip_nominal`,
:mod:`hbjax._diagnose.input_clip_nominal`)."""

from __future__ import annotations

import itertools
import math

import jax.numpy as jnp
import numpy as np

from .._misc import jsonable as _jsonable
from . import effects as fx
from . import residual_tests as rt
from .clip_nominal import N_FOLDS, fold_edges, held_base_refusal, other_blocks
from .decide import ANCHOR_ALPHA, BIC_MARGIN, DM_Z, over_constant
from .effect_base import ANCHORED
from .kernel import MAX_DELAY
from .result import Finding

#: key of the candidate table for the sensor curvature validated by folds
ON_NOMINAL = "output_nonlinearity (curvature of the nominal free run, folds)"
#: centres tried for the map, evenly over the fitted part's range of the nominal free run
CENTRES = 41
#: parameters: the centre and the two curvature coefficients
N_PARAMS = 3


def _fit_map(y, y_nom, scale, part):
    """``(center, k2, k3)`` minimising the free-run error of the map on the samples
    ``part``: for each of CENTRES centres over the range of ``y_nom[part]``, ``k2, k3`` by
    linear least squares; the best centre wins."""
    lo, hi = float(np.min(y_nom[part])), float(np.max(y_nom[part]))
    target = (y - y_nom)[part]
    best = (math.inf, 0.5 * (lo + hi), 0.0, 0.0)
    for c in np.linspace(lo, hi, CENTRES):
        z = (y_nom[part] - c) / scale
        X = scale * np.stack([z**2, z**3], axis=1)
        k, *_ = np.linalg.lstsq(X, target, rcond=None)
        sse = float(np.sum((target - X @ k) ** 2))
        if sse < best[0]:
            best = (sse, float(c), float(k[0]), float(k[1]))
    return best[1:]


def _mapped(y_nom, scale, center, k2, k3):
    z = (y_nom - center) / scale
    return y_nom + scale * (k2 * z**2 + k3 * z**3)


def output_map_on_nominal(ctx, model, y, v, n_fit, burn, ysim_all, u_all, stats, names):
    """The sensor curvature fitted on the nominal model's free run (base held) and
    cross-validated over ``N_FOLDS`` contiguous blocks of the whole record; tried only
    where the diagnosis found no mechanism and the curvature held on the nominal base
    (the candidate ``output_nonlinearity (nominal base)``) kept its base consistent
    (likelihood ratio p >= ANCHOR_ALPHA) without a significant held-out gain.

    Decision (all required): BIC gain of the mapped free run over the nominal one > BIC_MARGIN
    on the fitting segment (from the structural burn-in, ``N_PARAMS`` parameters); in the
    cross-validation, where each block's free run is mapped by a curvature fitted on the
    other blocks, a significantly smaller error over the record than the nominal free
    run's (Diebold-Mariano z > DM_Z) and a higher fit; the refit does not simulate the
    held-out part significantly better than the nominal model (a base that must move is
    not explained by a sensor alone), and the nominal model simulates it significantly
    better than a constant output.

    Returns ``(table_row | None, Finding | None)``."""
    label = "output_nonlinearity" + ANCHORED
    if label not in names:
        return None, None
    anchored = stats[names.index(label) + 1]
    base_p = anchored.get("base_p")
    if not (anchored.get("dbic", -math.inf) > BIC_MARGIN and base_p is not None
            and base_p >= ANCHOR_ALPHA):
        return None, None
    lay = ctx.lay
    y, y_nom = np.asarray(y, float), np.asarray(ysim_all[0], float)
    T = len(y)
    b0 = lay.na + lay.nb + MAX_DELAY + 4
    scale = float(np.std(y_nom[b0:n_fit])) or 1.0
    fitting = np.zeros(T, bool)
    fitting[b0:n_fit] = True
    center, k2, k3 = _fit_map(y, y_nom, scale, fitting)
    y_ext = _mapped(y_nom, scale, center, k2, k3)
    n = n_fit - b0
    sse_nom = float(np.sum((y - y_nom)[fitting] ** 2))
    sse_ext = float(np.sum((y - y_ext)[fitting] ** 2))
    dbic = n * math.log(max(sse_nom, 1e-300) / max(sse_ext, 1e-300)) - N_PARAMS * math.log(n)
    # BIC of the free run on the window of the other candidates (ranks it where the
    # diagnosis runs on the output error; placed by the held-out free run otherwise)
    r_main = (y - y_ext)[burn:n_fit]
    bic = (n_fit - burn) * math.log(max(float(np.sum(r_main**2)), 1e-300) / (n_fit - burn)) \
        + N_PARAMS * math.log(n_fit - burn)
    row = {"bic": bic, "k": N_PARAMS, "dbic_from_burn_in": dbic, "burn_in": b0, "center": center,
           "scale": scale, "k2": k2, "k3": k3,
           "fit_sim": rt.fit_percent_unchecked(y[n_fit:], y_ext[n_fit:])}
    if not dbic > BIC_MARGIN:
        row["decision"] = "BIC gain of the free run on the fitting segment not above the margin"
        return row, None
    validation = _folds(y, y_nom, scale, b0)
    row["folds"] = validation
    ref_i = names.index("parameter_mismatch") + 1
    fit_refit, dm_refit = float(stats[ref_i]["fit_sim"]), stats[ref_i].get("dm_z", 0.0)
    dm_const = over_constant(y, n_fit, burn, y[n_fit:] - y_nom[n_fit:])
    row["dm_z_over_constant"] = dm_const
    why = held_base_refusal(validation, dm_refit, dm_const, "a sensor curvature")
    row["decision"] = why or "reported"
    if why is not None:
        return row, None
    ext = fx.OutputNonlinearity(model, jnp.asarray(k2), jnp.asarray(k3), center, scale)
    info = dict(y=y, v=v, n_fit=n_fit, ysim=y_ext, ysim_ref=y_nom, u=np.asarray(u_all[0]))
    text = ext.describe(ctx, info)
    evidence = {
        "variant": "sensor curvature fitted on the nominal model (base parameters held fixed)",
        "validation": validation, "reference": "nominal", "base": "nominal (held)",
        "delta_bic_vs_nominal": dbic, "bic": bic, "bic_criterion": "simulation",
        "dm_z": validation["dm_z"], "dm_z_over_constant": dm_const,
        "reference_fit": validation["fit_nominal"], "refit_fit": fit_refit,
        "base_p": base_p, "parameters_fitted": N_PARAMS, "kind": "mechanism",
    }
    return row, Finding(
        effect="output_nonlinearity", physics=text["physics"], where=_jsonable(text["where"]),
        parameters=_jsonable(text["parameters"]), model=ext, metric="simulation",
        fit_before=validation["fit_nominal"], fit_after=validation["fit_map"],
        evidence=_jsonable(evidence))


def _folds(y, y_nom, scale, b0):
    """Cross-validation over ``N_FOLDS`` contiguous blocks from the structural burn-in
    ``b0``: each block's free run mapped by the curvature fitted on the other blocks. See
    :func:`output_map_on_nominal` for the acceptance rule."""
    T = len(y)
    edges = fold_edges(T, b0)
    y_cv = np.array(y_nom, dtype=float)
    fold_maps = []
    for lo_edge, hi_edge in itertools.pairwise(edges):
        center, k2, k3 = _fit_map(y, y_nom, scale, other_blocks(T, b0, lo_edge, hi_edge))
        fold_maps.append({"center": center, "k2": k2, "k3": k3})
        y_cv[lo_edge:hi_edge] = _mapped(y_nom[lo_edge:hi_edge], scale, center, k2, k3)
    r_nom, r_cv = (y - y_nom)[b0:], (y - y_cv)[b0:]
    dm = rt.diebold_mariano(r_nom, r_cv)
    fit_nom = rt.fit_percent_unchecked(y[b0:], y_nom[b0:])
    fit_cv = rt.fit_percent_unchecked(y[b0:], y_cv[b0:])
    accepted = bool(np.all(np.isfinite(r_cv)) and dm > DM_Z and fit_cv > fit_nom)
    return {"by": f"{N_FOLDS} folds of the whole record", "accepted": accepted,
            "dm_z": float(dm), "fit_nominal": float(fit_nom), "fit_map": float(fit_cv),
            "fold_maps": fold_maps, "fold_edges": [int(e) for e in edges]}
