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
"""

import dataclasses

import jax.numpy as jnp

from .._results import RESULTS


def judge_branches(res):
    """`res` (a :class:`hbjax.FitResult`) with its success turned into
    ``RESULTS.branches_undetermined`` where a branch coefficient is unidentified
    (traceable)."""
    m = res.model.backlash.m
    seen = jnp.all(res.identified[res.identified.shape[0] - 2 * m:])
    result = RESULTS.where((res.result == RESULTS.successful) & ~seen,
                           RESULTS.branches_undetermined, res.result)
    return dataclasses.replace(res, result=result)
