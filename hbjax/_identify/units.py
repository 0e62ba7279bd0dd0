"""The output's unit, taken out of the solver's numbers.

The criteria are invariant to the unit of ``y``: dividing every output by ``s`` divides the
optimal branches by ``s`` (``y / s = (B / A)(P / s)``) and changes nothing else. The
solver is not: its tolerances are absolute and its damping and pseudo-inverses compare
parameters of mixed units (``A`` is unitless, the branches carry the unit of ``y`` in the
``B(1) = 1`` gauge, ``B`` does in the paper's). Measured before this module: the same
record in volts and in micro-volts gave free-run fits of 99.0 % and 88.5 % (the solver
stopped where the micro-volt residuals already looked small), and a record in mega-units
halved the reported standard errors (the pseudo-inverse dropped the small-unit directions).
Refinement therefore solves on the outputs divided by their root mean square and carries
the model, covariance, noise level and costs back to the user's unit
(:func:`refine_in_unit`).
"""

import equinox as eqx
import jax.numpy as jnp

from .._core.arx import ARX
from .._core.backlash import Backlash
from .._core.model import Hammerstein
from .criteria import unpack, where_valid
from .parametrisation import PAPER


def output_scale(recordings):
    """Root mean square of the outputs over every recorded sample (1 if they are all 0)."""
    total, count = 0.0, 0
    for rec in recordings:
        _, y, mask = unpack(rec)
        total = total + jnp.sum(where_valid(mask, y, 0.0) ** 2)
        count = count + (y.shape[0] if mask is None else jnp.sum(mask))
    rms = jnp.sqrt(total / count)
    return jnp.where((rms > 0) & jnp.isfinite(rms), rms, 1.0)


def _outputs_divided(recordings, s):
    return tuple((rec[0], rec[1] / s) + tuple(rec[2:]) for rec in recordings)


def _output_times(model: Hammerstein, s, gauge: str) -> Hammerstein:
    """``model`` with its output multiplied by ``s``, in `gauge`'s normalisation: the
    paper's gauge keeps ``P2(-h_m) - P1(h_m)`` and scales ``B``; ``B(1) = 1`` keeps ``B``
    and scales the branches."""
    bl, arx = model.backlash, model.arx
    if gauge == PAPER:
        return Hammerstein(bl, ARX(arx.a, arx.b * s))
    return Hammerstein(Backlash(bl.c1 * s, bl.c2 * s), arx)


def _unit_vector(model: Hammerstein, s, gauge: str):
    """Per parameter (in :func:`hbjax.flatten_params` order): ``s`` where it carries the
    output's unit, 1 elsewhere."""
    na, nb, m = model.arx.a.shape[0], model.arx.b.shape[0], model.backlash.c1.shape[0]
    ones = lambda k: jnp.ones(k)  # noqa: E731
    if gauge == PAPER:
        return jnp.concatenate([ones(na), ones(nb) * s, ones(2 * m)])
    return jnp.concatenate([ones(na + nb), ones(2 * m) * s])


def refine_in_unit(solve, model: Hammerstein, recordings, gauge: str):
    """``solve(model, recordings)`` (a refinement returning an
    :class:`hbjax._identify.refine_result.AbstractRefinement`) run on the outputs divided by
    their root mean square ``s`` (the start's output divided alike), with the result's
    model, covariance, noise level and costs carried back to the recordings' unit."""
    s = output_scale(recordings)
    # The start's output over s, in any gauge: the solve normalises it first.
    start = Hammerstein(Backlash(model.backlash.c1 / s, model.backlash.c2 / s), model.arx)
    res = solve(start, _outputs_divided(recordings, s))
    f = _unit_vector(res.model, s, gauge)
    stats = dict(res.stats)
    for name in ("cost", "initial_cost"):
        stats[name] = stats[name] * s**2
    return eqx.tree_at(
        lambda r: (r.model, r.covariance, r.noise_std, r.stats),
        res, (_output_times(res.model, s, gauge), res.covariance * jnp.outer(f, f),
              res.noise_std * s, stats))
