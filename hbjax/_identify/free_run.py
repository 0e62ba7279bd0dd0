"""Whether a fit's estimate determines its own free run at all.

The free-run fit floor (:data:`hbjax._identify.quality.SIM_FIT_FLOOR`, 0 %: a model that
simulates worse than the output's mean is not a success) judges the estimate. Its
covariance judges the neighbourhood the records leave open: where the free run's
standard deviation, pooled over the estimation records, exceeds the output's own spread
by more than ``100 - floor`` percent (:func:`hbjax._identify.loop.free_run_spread`), a
parameter draw as likely as the estimate simulates the records worse than the floor, and
the estimate's own figure says nothing. Such a fit is ``RESULTS.free_run_undetermined``.

Measured (``benchmarks/RESULTS.md``): on ``benchmarks/fit_offsets.py --seed 5``, record 10
(T = 300, swept sine, 5 % noise), `fit` had reported a success 70 ``sigma^2`` above the true
system's refined cost, validating at -63 % (the truth's refinement: 86 %): its spread is
1.0e5 %, its ``b`` ~ 1e5 in ``B(1) = 1`` with standard errors ~ 1e8. The successes of
``identify_random.py --fit`` (seeds 3 and 6, 155 fits) reach at most 8 %; near-differencing
systems of the independent generator 1.3-36 %; the BRFD records 3-31 %; the Cascaded Tanks
1.9 %.
"""

import dataclasses

import jax.numpy as jnp

from .._results import RESULTS
# (the loop judgement's compiled spread: one program for both judgements)
from .loop import _spread_jit


def judge_free_run(res, recordings):
    """`res` (a concrete :class:`hbjax.FitResult`) with `free_run_spread` set where it is a
    success, and its result ``RESULTS.free_run_undetermined`` where that spread is finite
    and above ``100 - res.min_sim_fit`` percent. An infinite spread (an unidentified
    parameter moving the free run) is left to the judgements of unidentified parameters."""
    if res.result != RESULTS.successful:
        return res
    recordings = tuple(tuple(jnp.asarray(a) for a in rec) for rec in recordings)
    spread = _spread_jit(res.model, res.covariance, recordings)
    undetermined = bool(jnp.isfinite(spread)) and float(spread) > 100.0 - float(res.min_sim_fit)
    return dataclasses.replace(
        res, free_run_spread=spread,
        result=RESULTS.free_run_undetermined if undetermined else res.result)
