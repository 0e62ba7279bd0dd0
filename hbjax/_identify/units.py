"""The output's unit, taken out of the solve: refinement runs on ``y / s`` with ``s`` the
power of two nearest above the largest ``|y|``, and its result is carried back to ``y``.

Why: the Levenberg–Marquardt tolerances (optimistix's Cauchy termination) are absolute in
the residuals and the free parameters, and the covariance's pseudo-inverse cut singular
values relative to the largest one, over parameters in mixed units (it is now taken on the
column-normalised matrix, :func:`hbjax._identify.quality.gauss_newton_inverse`). Without this step a
record in micro-units stopped at its start and reported success, and one in mega-units
halved its standard errors. The inputs are scaled the same way already (the
parametrisation's ``scale``).

Why a power of two: dividing by it is exact in floating point, and it commutes exactly
with every product and sum that the compiler may reassociate; a general ``s`` changed the
bits of a sharded batch of refinements between device counts.

Which coefficients carry the unit depends on the gauge that fixes ``(A, mu B, P/mu)``:
with ``B(1) = 1`` the backlash carries it (``c1, c2`` scale with ``y``), with the paper's
``P2(-h_m) - P1(h_m) = 1`` (section 4.1) the numerator ``b`` does.
"""

import dataclasses

import jax.numpy as jnp

from .._core.backlash import Backlash
from .._core.model import Hammerstein
from .._core.params import flatten_params, model_from_theta
from .criteria import unpack, where_valid
from .parametrisation import PAPER


def output_unit(recordings):
    """The power of two ``2^e`` with ``max |y| / 2^e`` in ``[0.5, 1)`` over the recorded
    samples of all records (1 where every output is 0 or one is not finite)."""
    peak = jnp.max(jnp.stack([jnp.max(where_valid(mask, jnp.abs(y), 0.0))
                              for _, y, mask in map(unpack, recordings)]))
    _, exponent = jnp.frexp(peak)  # exact: no logarithm whose last bit may vary
    usable = jnp.isfinite(peak) & (peak > 0)
    return jnp.where(usable, jnp.ldexp(jnp.ones_like(peak), exponent), 1.0)


def in_unit(recordings, unit):
    """The records with their outputs divided by ``unit`` (padded records keep their
    sample count)."""
    return tuple((record[0], record[1] / unit) + tuple(record[2:]) for record in recordings)


def model_in_unit(model: Hammerstein, unit) -> Hammerstein:
    """The model of ``y / unit``: its backlash divided by ``unit`` (any gauge; the solve
    normalises it)."""
    bl = model.backlash
    return Hammerstein(Backlash(bl.c1 / unit, bl.c2 / unit), model.arx)


def unit_weights(gauge: str, na: int, nb: int, m: int, unit):
    """Per flattened parameter (``a, b, c1, c2``), the factor that carries the estimate of
    ``y / unit`` back to ``y`` in ``gauge``."""
    index = jnp.arange(na + nb + 2 * m)
    carried = (index >= na) & (index < na + nb) if gauge == PAPER else index >= na + nb
    return jnp.where(carried, unit, 1.0)


def result_from_unit(res, unit):
    """A refinement result on ``y / unit`` carried back to ``y``: the model, covariance,
    noise level and costs; fit percentages, p-values and input ranges are unit-free."""
    na, nb, m = res.model.arx.na, res.model.arx.nb, res.model.backlash.m
    w = unit_weights(res.gauge, na, nb, m, unit)
    model = model_from_theta(flatten_params(res.model) * w, na, nb)
    stats = dict(res.stats)
    for name in ("cost", "initial_cost"):
        stats[name] = stats[name] * unit**2
    return dataclasses.replace(res, model=model, stats=stats,
                               covariance=res.covariance * w[:, None] * w[None, :],
                               noise_std=res.noise_std * unit)
