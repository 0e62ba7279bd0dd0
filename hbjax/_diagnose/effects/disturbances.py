"""Disturbance effects: coloured equation error, a slow output drift and an additive
sinusoid unrelated to the input."""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import EffectConstraint, neutral_ints
from ..explain import rounded
from ..kernel import drift
from ..kernel_effect import AbstractKernelEffect, put
from ..residual_tests import periodogram, spectral_peaks


class ColoredNoise(AbstractKernelEffect):
    """Coloured equation error: ``A y = B u + xi / D`` with
    ``D = 1 + d[0] q^-1 + d[1] q^-2`` (an ARARX noise model). The simulation is the
    nominal one; the predictor whitens with ``D A``."""

    base: Hammerstein
    d: Float[Array, " 2"]

    name: ClassVar[str] = "colored_noise"
    slots: ClassVar[dict] = {"d": "noise_d"}
    constraints: ClassVar[dict] = {"d": EffectConstraint((2,))}

    @classmethod
    def candidate(cls, ctx):
        return cls.nominal_candidate(ctx, [("noise_d", 1.0)])

    def describe(self, ctx, info):
        d = np.asarray(self.d)
        roots = np.roots(np.concatenate([[1.0], d]))
        return {
            "physics": ("The disturbance is not white equation error: it is correlated in "
                        "time (coloured noise), so a noise model D improves prediction but "
                        "not simulation."),
            "where": {"windows": [[0, len(info["y"])]],
                      "regime": "whole record (disturbance spectrum)"},
            "parameters": {"d": d, "noise_poles": [[rounded(r.real), rounded(r.imag)]
                                                   for r in roots]},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        rho = float(rng.uniform(0.8, 0.95))
        return cls(base, jnp.asarray([-rho, 0.0])), base, {"pole": rho}


class OffsetDrift(AbstractKernelEffect):
    """Slow additive output drift, linear or settling:
    ``y = y_lin + offset + rate (1 - exp(-decay t)) / decay`` (t in samples), which is
    ``offset + rate t`` at ``decay = 0`` and, for ``decay > 0``, a drift that starts at
    ``rate`` per sample and settles with time constant ``1 / decay`` samples (a sensor or
    a housing coming to its working temperature). With the linear form alone, a settling
    drift extrapolated into the held-out part overshot it and a parameter change, whose
    step holds a level, simulated that part better: 3 of 5 settling drifts of the
    independent generator's seeds 1366-1367 were named a parameter change
    (benchmarks/RESULTS.md)."""

    base: Hammerstein
    offset: Float[Array, ""]
    rate: Float[Array, ""]
    decay: Float[Array, ""] = 0.0

    name: ClassVar[str] = "offset_drift"
    slots: ClassVar[dict] = {"offset": "drift_offset", "rate": "drift_rate",
                             "decay": "drift_decay"}
    constraints: ClassVar[dict] = {"offset": EffectConstraint(), "rate": EffectConstraint(),
                                   "decay": EffectConstraint()}

    @classmethod
    def candidate(cls, ctx):
        return cls.nominal_candidate(ctx, [("drift_offset", 1.0), ("drift_rate", 1.0 / ctx.n),
                                           ("drift_decay", 1.0 / ctx.n)])

    def level(self, n):
        """The drift ``offset + rate (1 - exp(-decay t)) / decay`` at ``t = 0 .. n - 1``
        (the kernel's :func:`hbjax._diagnose.kernel.drift`, its one home)."""
        lay, theta = self.parts()[:2]
        return np.asarray(drift(lay, theta, jnp.arange(n, dtype=theta.dtype))[0])

    def describe(self, ctx, info):
        n = len(info["y"])
        rate, k = float(self.rate), float(self.decay)
        level = self.level(n)
        change = float(level[-1] - level[0])
        settling = k * n > 0.5
        if settling:
            physics = (f"The output drifts by {rounded(change)} over the record, settling "
                       f"with time constant {rounded(1.0 / k)} samples (a sensor or housing "
                       "coming to its working temperature), on top of what the input "
                       "explains.")
        else:
            physics = (f"The output drifts slowly by {rounded(change)} over the record "
                       "(sensor or thermal drift) on top of what the input explains.")
        return {
            "physics": physics,
            "where": {"windows": [[0, n]],
                      "regime": "settles with time" if settling else "grows with time"},
            "parameters": {"offset": rounded(self.offset), "rate": rate, "decay": k,
                           "time_constant": rounded(1.0 / k) if k > 0 else None,
                           "drift_over_record": rounded(change)},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        rate = float(rng.choice([-1, 1]) * 0.6 * signals["sy"] / signals["n"])
        return cls(base, jnp.asarray(0.0), jnp.asarray(rate)), base, {"rate": rate}


class PeriodicDisturbance(AbstractKernelEffect):
    """An additive sinusoid unrelated to the input:
    ``y = y_lin + cos_amp cos(2 pi f t) + sin_amp sin(2 pi f t)``, ``f`` in cycles/sample."""

    base: Hammerstein
    frequency: Float[Array, ""]
    cos_amp: Float[Array, ""]
    sin_amp: Float[Array, ""]

    name: ClassVar[str] = "periodic_disturbance"
    slots: ClassVar[dict] = {"frequency": "sin_freq", "cos_amp": "sin_cos",
                             "sin_amp": "sin_sin"}
    # (any finite frequency: f, f + 1 and -f are the same line, and the fit is free)
    constraints: ClassVar[dict] = {"frequency": EffectConstraint(), "cos_amp": EffectConstraint(),
                                   "sin_amp": EffectConstraint()}

    @classmethod
    def candidate(cls, ctx):
        """Starts at the strongest residual spectral peaks away from the input's spectrum,
        amplitudes by least squares on the simulation residual."""
        n, burn = ctx.n, ctx.burn
        res = ctx.y_fit - ctx.y_sim_nom
        peaks = spectral_peaks(ctx.eps_nom[burn:], count=4,
                               exclude=periodogram(ctx.v_fit[burn:]))
        t = np.arange(n)
        starts = []
        for f, _ in peaks or [(0.25, 1.0)]:
            X = np.stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)], 1)
            coef = np.linalg.lstsq(X[burn:], res[burn:] - res[burn:].mean(), rcond=None)[0]
            starts.append((put(ctx, sin_freq=f, sin_cos=coef[0], sin_sin=coef[1]),
                           neutral_ints()))
        free = [("sin_freq", 1.0 / (2 * np.pi * n)), ("sin_cos", 1.0), ("sin_sin", 1.0)]
        return cls.nominal_candidate(ctx, free, starts=starts, grid=max(2, n // 2))

    def describe(self, ctx, info):
        f = float(self.frequency)
        amp = math.hypot(float(self.cos_amp), float(self.sin_amp))
        phase = math.atan2(-float(self.sin_amp), float(self.cos_amp))
        from .harmonic import harmonic_order

        harmonic = harmonic_order(f, np.asarray(info["v"])) if f > 0 else None
        if harmonic is None:
            origin = "unrelated to the input: mains hum, a rotating part or vibration."
        else:  # a line at a harmonic of the input's own line is input-driven
            origin = (f"at {harmonic[0]} times the input's line at {rounded(harmonic[1])} "
                      "cycles/sample: driven by the input (harmonic distortion), not a "
                      "disturbance unrelated to it.")
        return {
            "physics": (f"An additive sinusoid of amplitude {rounded(amp)} at {rounded(f)} "
                        f"cycles/sample (period {rounded(1 / f if f else np.inf)} samples) "
                        + origin),
            "evidence": {"harmonic_of_input": None if harmonic is None else
                         {"order": harmonic[0], "input_line": harmonic[1]}},
            "where": {"windows": [[0, len(info["y"])]], "frequency": f,
                      "regime": "whole record, narrow band"},
            "parameters": {"frequency": f, "amplitude": amp, "phase": phase,
                           "period_samples": 1 / f if f else None},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        f = float(rng.uniform(0.05, 0.3))
        amp = 0.2 * signals["sy"]
        return cls(base, jnp.asarray(f), jnp.asarray(amp), jnp.asarray(0.3 * amp)), base, \
            {"frequency": f}
