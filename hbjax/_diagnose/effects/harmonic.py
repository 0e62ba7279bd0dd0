"""Harmonic distortion: output lines at harmonics of the input's frequencies, driven by the
input (a static nonlinearity of the input seen at the output), as opposed to a periodic
disturbance unrelated to the input."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import AbstractEffect, EffectConstraint, base_model, effect_error
from ..explain import rounded


def input_fundamental(v, min_share=0.1):
    """The input's strongest spectral lines (cycles/sample, power above ``min_share`` of the
    peak, strongest first) and the record's frequency resolution ``1 / n``."""
    v = np.asarray(v, dtype=np.float64)
    spec = np.abs(np.fft.rfft(v - v.mean())) ** 2
    f = np.fft.rfftfreq(len(v))
    spec[0] = 0.0
    if not np.any(spec > 0):
        return [], 1.0 / len(v)
    idx = np.flatnonzero(spec >= min_share * spec.max())
    idx = idx[np.argsort(-spec[idx])][:8]
    return [float(f[i]) for i in idx], 1.0 / len(v)


def harmonic_order(freq, v, max_order=10, tol=1.5):
    """``(k, f_line)`` if ``freq`` is within ``tol + k / 2`` resolution bins of ``k`` times one of
    the input's strong lines (``k >= 2``), else ``None``."""
    lines, res = input_fundamental(v)
    best = None
    for fl in lines:
        if fl <= 0:
            continue
        k = round(freq / fl)
        near = 2 <= k <= max_order and abs(freq - k * fl) <= (tol + 0.5 * k) * res
        if near and (best is None or fl < best[1]):
            best = (k, fl)
    return best


class HarmonicDistortion(AbstractEffect):
    """An input-driven static term at the output: ``y = y_lin + h1 z + h2 z^2 + h3 z^3``,
    ``z = v / v_scale`` (``v_scale = max |v|``). For a sinusoidal input ``z = cos(w t)``
    the quadratic and cubic terms are lines at twice (amplitude ``h2 / 2``) and three
    times (``h3 / 4``) the input's frequency: harmonic distortion (a force proportional
    to the square of a current, a nonlinear transducer), locked to the input."""

    base: Hammerstein
    h1: Float[Array, ""]
    h2: Float[Array, ""]
    h3: Float[Array, ""]
    v_scale: Float[Array, ""]

    name: ClassVar[str] = "harmonic_distortion"
    n_params: ClassVar[int] = 3
    constraints: ClassVar[dict] = {"h1": EffectConstraint(), "h2": EffectConstraint(),
                                   "h3": EffectConstraint(),
                                   "v_scale": EffectConstraint(positive=True)}

    @classmethod
    def from_params(cls, base, params, consts=None):
        scale = jnp.asarray(1.0) if consts is None else jnp.asarray(consts[0])
        return cls(base, params[0], params[1], params[2], scale)

    def params(self):
        return jnp.stack([jnp.asarray(self.h1), jnp.asarray(self.h2), jnp.asarray(self.h3)])

    def output_term(self, v, u, y_lin):
        z = v / self.v_scale
        return self.h1 * z + self.h2 * z**2 + self.h3 * z**3

    @classmethod
    def fit_error(cls, lay, theta, params, consts, v, y, criterion, u0=0.0):
        effect = cls.from_params(base_model(lay, theta), params, consts)
        return effect_error(effect, lay, theta, consts, v, y, criterion, u0)

    @classmethod
    def from_fit(cls, ctx, theta, ints, params=None):
        return cls.from_params(base_model(ctx.lay, theta), jnp.asarray(params), ctx.consts)

    @classmethod
    def start(cls, ctx):
        """Least squares of the simulation residual on the powers of the scaled input."""
        z = ctx.v_fit / float(ctx.consts[0])
        r = (ctx.y_fit - ctx.y_sim_nom)[ctx.burn:]
        X = np.stack([z, z**2 - np.mean(z**2), z**3], 1)[ctx.burn:]
        coef = np.linalg.lstsq(X, r - r.mean(), rcond=None)[0]
        return np.array([np.zeros(3), coef])

    @classmethod
    def scales(cls, ctx):
        return np.full(3, 0.1 * max(float(np.std(ctx.y_fit)), 1e-12))

    def describe(self, ctx, info):
        v = np.asarray(info["v"])
        amp2, amp3 = abs(float(self.h2)) / 2, abs(float(self.h3)) / 4
        lines, _res = input_fundamental(v)
        where = {"windows": [[0, len(v)]], "regime": "locked to the input (harmonics)"}
        if lines:
            f0 = min(lines)
            where["input_fundamental"] = f0
            text = (f" at {rounded(2 * f0)} and {rounded(3 * f0)} cycles/sample for the input's "
                    f"line at {rounded(f0)}")
        else:
            text = ""
        return {
            "physics": (f"An input-driven static nonlinearity at the output: for a full-scale "
                        f"sinusoidal input it adds a 2nd harmonic of amplitude {rounded(amp2)} "
                        f"and a 3rd of {rounded(amp3)}{text}. The lines follow the input "
                        "(harmonic distortion), they are not a disturbance unrelated to it."),
            "where": where,
            "parameters": {"h1": rounded(self.h1), "h2": rounded(self.h2),
                           "h3": rounded(self.h3), "v_scale": rounded(self.v_scale),
                           "second_harmonic": rounded(amp2), "third_harmonic": rounded(amp3)},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        v = signals["v"]
        amp = 0.3 * signals["sy"]
        scale = float(np.max(np.abs(v)))
        return cls(base, jnp.asarray(0.0), jnp.asarray(amp), jnp.asarray(0.5 * amp),
                   jnp.asarray(scale)), base, {"h2": amp, "h3": 0.5 * amp}
