"""Whether the records determine the branches a :func:`hbjax.fit` result reports.

A branch polynomial of ``m`` coefficients is determined only where the records hold the
input at enough distinct values while that branch decides the output. An input of a few
levels (a PRBS of three levels, a two-level square wave) or one that never falls leaves
some branch coefficients unidentified (``std = inf``, listed in ``.unidentified``): the
model then reproduces the records, but its branches between and beyond the recorded values
are whatever the starts left there. On fresh inputs of the same kind, with other levels,
10 of 12 such fits of random paper-class systems validated at 1.7-83.6 %, and two of
random closing-loop systems at 71.0 and 98.6 % (``benchmarks/RESULTS.md``, "Branches the
records do not determine"). So :func:`hbjax.fit`
calls that ``RESULTS.branches_undetermined``, not a success; the model is still returned
(``throw=False``). :func:`hbjax.refine` only reports the flags: it refines a model the
caller chose, on records the caller designed.

Identified coefficients are not yet a determined branch. With a few more levels than the
branch has coefficients, the records pin the branch at the levels and leave it open between
them: the estimate's covariance carried to the branch's value says so, many times larger
between the levels than at them. Such fits validated at -279 % to 92 % on inputs of other
levels, where fits of continuous inputs (ratio 1) and of levels that pin the branch
(ratio 1-1.9) validate at 97-100 % (``benchmarks/RESULTS.md``, "Branches known only at the
recorded levels"), so :func:`hbjax.fit` calls those ``RESULTS.branches_between_levels``.
"""

import dataclasses

import jax.numpy as jnp

from .._results import RESULTS
from .criteria import unpack, where_valid

# A branch is determined only at the recorded inputs where its standard deviation (the
# estimate's covariance carried to the branch's value) somewhere between them, inside the
# range where it decides the output, exceeds this many times its largest value at them.
# Measured (benchmarks/RESULTS.md, "Branches known only at the recorded levels"): 1
# on every record of continuous inputs (the largest is at a recorded input), 1-1.9 on the
# PRBS-levels successes that validated at 96.9-99.6 %, 4.95-47 on those that validated
# at -279-92 % on fresh levels.
INTERPOLATION_RATIO = 2.0
# Points of the grid over the active range on which the branch's deviation is taken.
_GRID = 201


def _interpolation_ratio(res, recordings, k):
    """Largest standard deviation of branch ``k`` (0: ``P1``, 1: ``P2``) on a grid over the
    range where it decides the output, over its largest at the recorded inputs there (1
    where the branch never decides; traceable)."""
    m = res.model.backlash.m
    lo, hi = res.active_ranges[k, 0], res.active_ranges[k, 1]
    active = jnp.isfinite(lo) & jnp.isfinite(hi)
    lo, hi = jnp.where(active, lo, 0.0), jnp.where(active, hi, 1.0)
    start = res.covariance.shape[0] - 2 * m + k * m
    cov = res.covariance[start:start + m, start:start + m]

    def deviation(x):
        powers = x[:, None] ** jnp.arange(m)
        return jnp.sqrt(jnp.maximum(jnp.einsum("gi,ij,gj->g", powers, cov, powers), 0.0))

    between = jnp.max(deviation(jnp.linspace(lo, hi, _GRID)))
    at = jnp.zeros(())
    for v, _, mask in map(unpack, recordings):
        inside = where_valid(mask, (v >= lo) & (v <= hi), False)
        at = jnp.maximum(at, jnp.max(jnp.where(inside, deviation(v), 0.0)))
    return jnp.where(active & (at > 0), between / jnp.where(at > 0, at, 1.0), 1.0)


def refuse_unseen(res):
    """`res` with its success turned into ``RESULTS.branches_undetermined`` where a branch
    coefficient is unidentified (traceable)."""
    m = res.model.backlash.m
    seen = jnp.all(res.identified[res.identified.shape[0] - 2 * m:])
    result = RESULTS.where((res.result == RESULTS.successful) & ~seen,
                           RESULTS.branches_undetermined, res.result)
    return dataclasses.replace(res, result=result)


def judge_branches(res, recordings):
    """`res` (a :class:`hbjax.FitResult`) with its `interpolation_ratio` set and its
    success turned into ``RESULTS.branches_undetermined`` where a branch coefficient is
    unidentified (:func:`refuse_unseen`), or into ``RESULTS.branches_between_levels``
    where a branch is determined only at the recorded inputs: between them, inside the
    range where it decides the output, its standard deviation exceeds
    :data:`INTERPOLATION_RATIO` times its largest at them (an input of a few levels, whose
    polynomial between the levels the covariance leaves open). Traceable."""
    # (an infinite covariance is an unidentified parameter, judged here, or a refused fit)
    finite = jnp.all(jnp.isfinite(res.covariance))
    ratio = jnp.where(finite, jnp.maximum(_interpolation_ratio(res, recordings, 0),
                                          _interpolation_ratio(res, recordings, 1)), jnp.nan)
    between = (res.result == RESULTS.successful) & finite & (ratio > INTERPOLATION_RATIO)
    result = RESULTS.where(between, RESULTS.branches_between_levels, res.result)
    return refuse_unseen(dataclasses.replace(res, result=result, interpolation_ratio=ratio))
