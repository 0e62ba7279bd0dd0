"""Identifying a nominal HB-Hammerstein model from an ordinary recording, for diagnosis
examples on real data (cascaded tanks, BRFD): a linear least-squares start followed by
Levenberg-Marquardt on the prediction error (the same compiled engine as the diagnosis).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._core.arx import ARX
from .._core.backlash import Backlash
from .._core.cache import ensure_compilation_cache
from .._core.model import Hammerstein
from .._core.precision import require_x64
from .._identify.linear import arx_least_squares
from .._identify.recordings import check_criterion
from .._misc import as_float_array, check_finite, positive_float, positive_int, same_length
from . import candidates as cands
from .kernel import MAX_DELAY
from .kernel_effect import base_theta
from .solve import fit_batch


def _static_start(v, y, na, nb, m, gap):
    """A stable start for output-error fits: the static least-squares line ``y = g v + c``
    behind a first-order lag (pole 0.5), the backlash a narrow band around it."""
    g, c = np.polyfit(v, y, 1)
    a = np.zeros(na)
    a[0] = -0.5
    b = np.zeros(nb)
    b[0] = 0.5
    c1 = np.zeros(m)
    c1[0], c1[1] = c - gap * g, g
    c2 = c1.copy()
    c2[0] = c + gap * g
    return Hammerstein(Backlash(c1, c2), ARX(a, b))


def _linear_start(v, y, na, nb, m, gap):
    """ARX by least squares on ``v`` with a constant, as a model whose backlash is a narrow
    band ``[v - gap, v + gap]`` around the identity (offset folded into the branches)."""
    theta = np.asarray(arx_least_squares([(jnp.asarray(v), jnp.asarray(y))], na, nb,
                                         skip=max(na, nb), constant=True))
    a, b, const = theta[:na], theta[na:na + nb], theta[-1]
    c0 = const / (np.sum(b) or 1.0)
    c1 = np.zeros(m)
    c1[0], c1[1] = c0 - gap, 1.0
    c2 = c1.copy()
    c2[0] = c0 + gap
    return Hammerstein(Backlash(c1, c2), ARX(a, b))


def _orders(start, na, nb, m):
    """``(na, nb, m)``: given, else the start's, else 2, 2 and 3; a start must be a
    :class:`Hammerstein` whose orders agree with any given."""
    if start is not None:
        if not isinstance(start, Hammerstein):
            raise TypeError(f"`start` must be an hbjax.Hammerstein, got {type(start).__name__}.")
        own = {"na": start.arx.na, "nb": start.arx.nb, "m": start.backlash.m}
        given = {"na": na, "nb": nb, "m": m}
        for name, value in given.items():
            if value is not None and value != own[name]:
                raise ValueError(f"`{name}`={value!r} differs from the `start` model's "
                                 f"{name} = {own[name]}: the fit keeps the start's structure.")
        return own["na"], own["nb"], own["m"]
    na = positive_int(2 if na is None else na, "na", minimum=0)
    nb = positive_int(2 if nb is None else nb, "nb")
    m = positive_int(3 if m is None else m, "m")
    if m < 2:
        raise ValueError(f"`m` must be >= 2 (affine branches at least), got {m}.")
    return na, nb, m


def identify_nominal(v, y, *, na: int | None = None, nb: int | None = None,
                     m: int | None = None, gap: float | None = None,
                     start: Hammerstein | None = None, max_steps: int = 200,
                     criterion: str = "prediction", transient: int = 0) -> Hammerstein:
    """Prediction-error HB-Hammerstein model of ``(v, y)`` (eq. (10) structure).

    **Arguments:** `v`, `y` (recording), `na`, `nb`, `m` (orders, default 2, 2 and 3, or
    those of `start`; branch degree ``m - 1``), `gap` (half-width of the initial backlash
    band, a number > 0, default 2% of the input range), `start` (an
    :class:`hbjax.Hammerstein` to start from instead of the linear least-squares one; its
    orders are the fit's), `max_steps` (>= 1), `criterion` (``"prediction"`` or
    ``"simulation"``: output error, better for slow processes), `transient` (samples at
    the start left out of the criterion, ``0 <= transient`` and fewer than the record
    holds).
    """
    require_x64("identify_nominal")
    ensure_compilation_cache()
    v = np.asarray(check_finite(as_float_array(v, "v", ndim=1, dtype=jnp.float64), "v"))
    y = np.asarray(check_finite(as_float_array(y, "y", ndim=1, dtype=jnp.float64), "y"))
    same_length(v=v, y=y)
    na, nb, m = _orders(start, na, nb, m)
    max_steps = positive_int(max_steps, "max_steps")
    check_criterion(criterion)
    transient = positive_int(transient, "transient", minimum=0)
    if transient >= v.shape[0]:
        raise ValueError(f"`transient` must leave samples in the criterion: it is {transient} "
                         f"for a record of {v.shape[0]} samples.")
    if gap is not None and start is not None:
        raise ValueError("`gap` sets the band of the linear least-squares start; with `start` "
                         "given it has no effect: pass one of them.")
    if gap is not None:
        gap = positive_float(gap, "gap")
    if start is None:
        gap = 0.02 * float(np.ptp(v)) if gap is None else gap
        make = _static_start if criterion == "simulation" else _linear_start
        start = make(v, y, na, nb, m, gap)
    lay, theta0 = base_theta(start)
    S = cands.base_selection(lay, theta0, lay.p_base + 4)
    consts = jnp.asarray([max(float(np.max(np.abs(v))), 1e-12), float(np.mean(y)),
                          max(float(np.std(y)), 1e-12), 1.0])
    ints = jnp.asarray(cands._ints())[None]
    theta, _, _ = fit_batch(lay, theta0[None], jnp.asarray(S)[None], ints, consts,
                            jnp.asarray(v), jnp.asarray(y),
                            max(lay.na + lay.nb + MAX_DELAY + 4, int(transient)),
                            max_steps, False, criterion)
    model = cands.base_model(lay, theta[0])
    # an output-error fit can wander into an unstable linear block; keep the start then
    return model if model.arx.is_stable() or not start.arx.is_stable() else start
