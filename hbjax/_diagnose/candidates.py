"""Candidate extensions of the diagnosis: start values from the residual signatures, the
free parameters each effect adds, and turning a fitted vector back into a physical model.

Every effect is expressed in the extended parameter vector of
:mod:`hbjax._diagnose.kernel`; a candidate lists its possible starts (one is chosen by a
batched evaluation of the criterion) and the slots it frees, with a scale per slot so that
Levenberg-Marquardt sees well-conditioned columns.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from . import effects as fx
from .._core.arx import ARX
from .._core.backlash import Backlash
from .kernel import MAX_DELAY, Layout
from .._core.model import Hammerstein
from .residual_tests import periodogram, spectral_peaks

BASE_SLOTS = ("a", "b", "c1", "c2")


@dataclasses.dataclass
class Context:
    """What the candidate builders see: the fitting segment and the nominal model's
    behaviour on it (``*_nom`` arrays are over the fitting segment)."""

    lay: Layout
    theta_nom: jnp.ndarray
    consts: jnp.ndarray
    v_fit: np.ndarray
    y_fit: np.ndarray
    y_sim_nom: np.ndarray
    u_nom: np.ndarray
    eps_nom: np.ndarray
    burn: int
    change_scan: dict


@dataclasses.dataclass
class Candidate:
    effect: str
    starts: list  # of (theta0, ints)
    free: list  # of (slot, scale)
    k_ext: int
    grid: int = 1  # size of the discrete search behind the start (penalised)


def _ints(delay=0, time=fx.NO_CHANGE):
    return np.array([delay, time], dtype=np.int32)


def _put(ctx, **values):
    theta = ctx.theta_nom
    for name, val in values.items():
        theta = ctx.lay.put(theta, name, val)
    return theta


def _levels(x, side):
    """Clip-level starts: the extreme value (a flat top sits exactly there) and quantiles."""
    qs = (1.0, 0.995, 0.98, 0.95, 0.9, 0.8) if side > 0 else (0.0, 0.005, 0.02, 0.05, 0.1, 0.2)
    return [np.inf * side] + sorted({float(np.quantile(x, q)) for q in qs})


def _flat(y, side):
    """A clipped measurement sits exactly at its limit: several samples equal to the
    extreme (up to a relative 1e-9 of the range)."""
    ext = np.max(y) if side > 0 else np.min(y)
    tol = 1e-9 * (np.ptp(y) or 1.0)
    return int(np.sum(np.abs(y - ext) <= tol)) >= 3


def _saturation(ctx, effect, signal, lo, hi):
    ups, lows = _levels(signal, +1), _levels(signal, -1)
    if effect == "output_saturation":
        # a measured clip is flat: start such a side at the extreme, leave others open
        flat_hi, flat_lo = _flat(signal, +1), _flat(signal, -1)
        if flat_hi or flat_lo:
            ups = [np.inf, float(np.max(signal))] if flat_hi else [np.inf]
            lows = [-np.inf, float(np.min(signal))] if flat_lo else [-np.inf]
    starts = []
    for up in ups:
        for low in lows:
            if low < up:
                starts.append((_put(ctx, **{lo: low, hi: up}), _ints()))
    return Candidate(effect, starts, [], 2)


def build(ctx: Context, effects) -> list[Candidate]:
    n = len(ctx.y_fit)
    lay = ctx.lay
    out = []
    for name in effects:
        if name == "parameter_mismatch":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())], [], 0))
        elif name == "output_saturation":
            out.append(_saturation(ctx, name, ctx.y_fit, "out_lo", "out_hi"))
        elif name == "input_saturation":
            out.append(_saturation(ctx, name, ctx.u_nom, "in_lo", "in_hi"))
        elif name == "extra_delay":
            starts = [(ctx.theta_nom, _ints(delay=d)) for d in range(1, MAX_DELAY + 1)]
            out.append(Candidate(name, starts, [], 0, grid=MAX_DELAY))
        elif name == "unmodeled_dynamics":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())],
                                 [("a_extra", 1.0), ("b_extra", 1.0)], 2))
        elif name == "colored_noise":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())], [("noise_d", 1.0)], 2))
        elif name == "offset_drift":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())],
                                 [("drift_offset", 1.0), ("drift_rate", 1.0 / n)], 2))
        elif name == "parameter_change":
            tau = int(ctx.change_scan["time"])
            free = [(s, 1.0) for s in ("da", "db", "dc1", "dc2")]
            out.append(Candidate(name, [(ctx.theta_nom, _ints(time=tau))], free,
                                 lay.p_base - 1, grid=ctx.change_scan["grid"]))
        elif name == "periodic_disturbance":
            out.append(_periodic(ctx, name))
        elif name == "output_nonlinearity":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())],
                                 [("nl2", 1.0), ("nl3", 1.0)], 2))
        elif name == "coulomb_friction":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())], [("friction", 1.0)], 1))
        elif name == "branch_degree":
            out.append(Candidate(name, [(ctx.theta_nom, _ints())],
                                 [("c1_extra", 1.0), ("c2_extra", 1.0)], 2))
        else:  # pragma: no cover - names are validated by diagnose()
            raise ValueError(name)
    return out


def _periodic(ctx, name):
    """Starts at the strongest residual spectral peaks away from the input's spectrum,
    amplitudes by least squares on the simulation residual."""
    n = len(ctx.y_fit)
    res = ctx.y_fit - ctx.y_sim_nom
    peaks = spectral_peaks(ctx.eps_nom[ctx.burn:], count=4,
                           exclude=periodogram(ctx.v_fit[ctx.burn:]))
    t = np.arange(n)
    starts = []
    for f, _ in peaks or [(0.25, 1.0)]:
        X = np.stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)], 1)
        coef = np.linalg.lstsq(X[ctx.burn:], res[ctx.burn:] - res[ctx.burn:].mean(),
                               rcond=None)[0]
        starts.append((_put(ctx, sin_freq=f, sin_cos=coef[0], sin_sin=coef[1]), _ints()))
    free = [("sin_freq", 1.0 / (2 * np.pi * n)), ("sin_cos", 1.0), ("sin_sin", 1.0)]
    return Candidate(name, starts, free, 3, grid=max(2, n // 2))


def fixed_b(lay: Layout, theta) -> int:
    """Index of the ``b`` coefficient held fixed: only ``(A, mu B, P / mu)`` is identifiable
    (paper section 4.1), so one scale is frozen (the largest ``b``) to remove the flat
    direction."""
    return int(np.argmax(np.abs(np.asarray(lay.get(theta, "b")))))


def selection(lay: Layout, cand: Candidate, theta0, K: int) -> np.ndarray:
    """The ``(P, K)`` matrix mapping the free parameters (base + extension) into theta."""
    slots = lay.slots()
    skip = {slots["b"][0] + fixed_b(lay, theta0), slots["db"][0] + fixed_b(lay, theta0)}
    cols = []
    free = [(s, 1.0) for s in BASE_SLOTS] + list(cand.free)
    if cand.effect in ("output_saturation", "input_saturation"):
        lo, hi = ("out_lo", "out_hi") if cand.effect == "output_saturation" else ("in_lo", "in_hi")
        for s in (lo, hi):
            if np.isfinite(float(lay.get(theta0, s)[0])):
                free.append((s, 1.0))
    for name, scale in free:
        start, stop = slots[name]
        for k in range(start, stop):
            if k in skip:
                continue
            col = np.zeros(lay.size)
            col[k] = scale
            cols.append(col)
    S = np.zeros((lay.size, K))
    S[:, :len(cols)] = np.stack(cols, 1)
    return S


def n_free(lay: Layout, cand: Candidate, theta) -> int:
    """Number of fitted parameters (the complexity in the information criterion)."""
    if cand.effect in ("output_saturation", "input_saturation"):
        lo, hi = ("out_lo", "out_hi") if cand.effect == "output_saturation" else ("in_lo", "in_hi")
        k = sum(np.isfinite(float(lay.get(theta, s)[0])) for s in (lo, hi))
        return lay.p_base - 1 + int(k)
    return lay.p_base - 1 + cand.k_ext


def base_model(lay: Layout, theta) -> Hammerstein:
    g = lambda s: jnp.asarray(lay.get(theta, s))  # noqa: E731
    return Hammerstein(Backlash(g("c1"), g("c2")), ARX(g("a"), g("b")))


def to_model(lay: Layout, effect: str, theta, ints, consts):
    """The fitted extension as its public effect class (``parameter_mismatch``: the
    refitted :class:`hbjax.Hammerstein`)."""
    base = base_model(lay, theta)
    g = lambda s: jnp.asarray(lay.get(theta, s)[0])  # noqa: E731

    def level(s):
        val = float(lay.get(theta, s)[0])
        return jnp.asarray(val) if math.isfinite(val) else None

    if effect == "parameter_mismatch":
        return base
    if effect == "output_saturation":
        return fx.OutputSaturation(base, level("out_lo"), level("out_hi"))
    if effect == "input_saturation":
        return fx.InputSaturation(base, level("in_lo"), level("in_hi"))
    if effect == "extra_delay":
        return fx.ExtraDelay(base, int(ints[0]))
    if effect == "unmodeled_dynamics":
        return fx.UnmodeledDynamics(base, g("a_extra"), g("b_extra"))
    if effect == "colored_noise":
        return fx.ColoredNoise(base, jnp.asarray(lay.get(theta, "noise_d")))
    if effect == "offset_drift":
        return fx.OffsetDrift(base, g("drift_offset"), g("drift_rate"))
    if effect == "parameter_change":
        d = {s: jnp.asarray(lay.get(theta, s)) for s in ("da", "db", "dc1", "dc2")}
        return fx.ParameterChange(base, int(ints[1]), **d)
    if effect == "periodic_disturbance":
        return fx.PeriodicDisturbance(base, g("sin_freq"), g("sin_cos"), g("sin_sin"))
    if effect == "output_nonlinearity":
        return fx.OutputNonlinearity(base, g("nl2"), g("nl3"), float(consts[1]), float(consts[2]))
    if effect == "coulomb_friction":
        return fx.CoulombFriction(base, g("friction"), float(consts[3]))
    if effect == "branch_degree":
        return fx.BranchDegree(base, g("c1_extra"), g("c2_extra"), float(consts[0]))
    raise ValueError(effect)  # pragma: no cover
