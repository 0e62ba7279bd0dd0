"""Other recorded channels: a missing input.

A recording often holds more than the input and output the model uses (a velocity, a
normal force, a supply voltage, a second actuator). When the nominal model's residual
follows such a channel, no single-input extension can represent it: the output depends on a
signal the model does not see. :func:`fit_missing_input` tests that, with the nominal base
held fixed (its free run ``y_nom``), by linear least squares on the fitting segment, for
every non-empty set of offered channels (singles, pairs, all) and two ways of entering:

- ``"input"``: the channel is a second input through the linear block's dynamics,
  ``y = y_nom + (1 / A) sum_k g_k w(t - k)``, ``k = 0..LAGS`` (a short FIR in the
  numerator; the denominator is the nominal ``A``, the plant's own poles);
- ``"slip"``: the channel scales the output level, ``y = y_nom (1 + sum_j s_j w_j(t))``
  (e.g. a friction force proportional to a recorded normal force: the slip level follows
  it);
- ``"input+slip"``: both.

``w`` are the channels centred and scaled on the fitting segment. Every model also has a
gain and an offset on ``y_nom``; the same regression without any channel is the
**reference**, so that the channel's share of the improvement is measured alone. Fitted on
the one-step prediction error ``A_nom (y - y_ext)`` (``criterion="prediction"``) or on the
output error (``"simulation"``). The best by BIC (with ``2 ln G`` for the ``G`` models tried)
is reported as ``missing_input`` only if it beats the reference by more than the BIC margin
and improves the **held-out free-run simulation** significantly against both the nominal
model and the reference (Diebold-Mariano z > 2), to a fit above both, and beats a constant
output on the held-out part (:func:`hbjax._diagnose.decide.over_constant`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import residual_tests as rt
from .decide import over_constant
from .effect_base import EffectConstraint
from .._core.arx import all_pole
from .._core.model import AbstractModel, Hammerstein
from .._misc import as_float_array, check_values, lag_sum, lagged

#: FIR lags 0..LAGS of a channel entering as a second input
LAGS = 3
VARIANTS = ("input", "slip", "input+slip")
#: channels more alike the measured output than this (|correlation|) are not inputs
SAME_AS_OUTPUT = 0.9999


def check_channels(channels, n: int) -> dict:
    """``channels`` as ``{name: float64 array of length n}`` (finite), or ``{}``."""
    if channels is None:
        return {}
    if not isinstance(channels, Mapping):
        raise TypeError(f"`channels` must be a dict of name -> array, got "
                        f"{type(channels).__name__}.")
    out = {}
    for name, w in channels.items():
        if not isinstance(name, str):  # (names reach reports, JSON and model files)
            raise TypeError(f"`channels` names must be strings, got {name!r}.")
        arr = np.asarray(as_float_array(w, f"channels[{name!r}]", dtype=np.float64, host=True))
        if arr.ndim != 1 or arr.shape[0] != n:
            raise ValueError(f"channel {name!r} must be a 1-D array of the record's length "
                             f"{n}, got shape {arr.shape}.")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"channel {name!r} contains NaN or infinite values.")
        # (the bound the record's own signals get: squares and products of larger values
        # overflow in the extension's fit)
        check_values(arr, f"channels[{name!r}]")
        out[str(name)] = arr
    return out


class MissingInput(AbstractModel):
    """The nominal model with recorded channels entering (``missing_input``):

    ``y = (1 + gain) y_lin + offset + sum_j s_j y_lin w_j + (1 / A) sum_j sum_k g_jk w_j(t - k)``

    with ``y_lin`` the nominal HB-Hammerstein output (eq. (10)), ``A`` its denominator and
    ``w_j = (channel_j - center_j) / scale_j`` the recorded channels (``signals``, one
    column per channel, the record's length). It runs on the record the channels were
    recorded with, or a prefix of it (:meth:`record_length`; a longer input is refused)."""

    base: Hammerstein
    signals: Float[Array, "time channels"]
    center: Float[Array, " channels"]
    scale: Float[Array, " channels"]
    taps: Float[Array, "channels lags"]
    slip: Float[Array, " channels"]
    gain: Float[Array, ""]
    offset: Float[Array, ""]
    channel_names: tuple = eqx.field(static=True)
    name: ClassVar[str] = "missing_input"

    def __check_init__(self):
        # Held to the rules of the effects (the model-file reader runs this too): a file
        # with a string for the base, a NaN channel sample or a zero scale is refused here,
        # naming the field, not deep inside a simulation.
        if not isinstance(self.base, Hammerstein):
            raise TypeError("`MissingInput.base` must be an hbjax.Hammerstein, got "
                            f"{type(self.base).__name__}.")
        names = self.channel_names
        if not (isinstance(names, tuple) and names
                and all(isinstance(c, str) for c in names)):
            raise TypeError("`MissingInput.channel_names` must be a non-empty tuple of "
                            f"strings, got {names!r}.")
        J = len(names)
        shape = np.shape(self.signals)
        if len(shape) != 2 or shape[0] < 1:
            raise ValueError("`MissingInput.signals` must be a 2-D array (samples x "
                             f"channels), got shape {shape}.")
        T = shape[0]
        rules = {"signals": EffectConstraint(shape=(T, J)),
                 "center": EffectConstraint(shape=(J,)),
                 "scale": EffectConstraint(shape=(J,), positive=True),
                 "taps": EffectConstraint(shape=(J, LAGS + 1)),
                 "slip": EffectConstraint(shape=(J,)),
                 "gain": EffectConstraint(), "offset": EffectConstraint()}
        for field, rule in rules.items():
            rule.check(f"MissingInput.{field}", getattr(self, field), self.base)

    def record_length(self) -> int:
        return int(self.signals.shape[0])

    def _extension(self, y_lin):
        T, n = y_lin.shape[0], self.signals.shape[0]
        # a prefix of the record sees the channels' prefix; samples past the record (only
        # the simulator's length padding, cut off afterwards) hold the last recorded value
        sig = self.signals[:T] if T <= n else jnp.concatenate(
            [self.signals, jnp.repeat(self.signals[-1:], T - n, axis=0)])
        w = (sig - self.center) / self.scale
        fir = sum(lagged(w[:, j], k) * self.taps[j, k]
                  for j in range(w.shape[1]) for k in range(self.taps.shape[1]))
        fir = all_pole(self.base.arx.a, fir + jnp.zeros_like(y_lin))
        return (1 + self.gain) * y_lin + self.offset + y_lin * (w @ self.slip) + fir

    def simulate_trajectory(self, v, noise, u0):
        return self._extension(self.base.simulate_trajectory(v, noise, u0))

    def predict_trajectory(self, v, y, u0):
        e = y - self.simulate_trajectory(v, jnp.zeros_like(v), u0)
        return y - (e + lag_sum(self.base.arx.a, e))


def _design(y_nom, w, a, variant):
    """Columns of the regression ``y - y_nom ~ X beta`` (gain, offset, then the channels')."""
    cols = [y_nom, np.ones_like(y_nom)]
    if variant in ("input", "input+slip"):
        from scipy.signal import lfilter  # (imported where used: 0.85 s of `import hbjax`)

        cols += [lfilter([1.0], np.r_[1.0, a], lagged(jnp.asarray(w[:, j]), k))
                 for j in range(w.shape[1]) for k in range(LAGS + 1)]
    if variant in ("slip", "input+slip"):
        cols += [y_nom * w[:, j] for j in range(w.shape[1])]
    return np.stack(cols, axis=1)


def _lstsq(X, t, a, window, criterion):
    """Coefficients minimising the criterion on ``window``; returns ``(beta, sse)``."""
    if criterion == "prediction":  # the one-step prediction error A (y - y_ext)
        from scipy.signal import lfilter  # (imported where used: 0.85 s of `import hbjax`)

        filt = lambda x: lfilter(np.r_[1.0, a], [1.0], x, axis=0)  # noqa: E731
        X, t = filt(X), filt(t)
    Xw, tw = X[window], t[window]
    scale = np.linalg.norm(Xw, axis=0)
    scale[scale == 0] = 1.0
    beta = np.linalg.lstsq(Xw / scale, tw, rcond=None)[0] / scale
    return beta, float(np.sum((tw - Xw @ beta) ** 2))


def fit_missing_input(model: Hammerstein, y, y_nom, channels: dict, n_fit: int, burn: int,
                      criterion: str, bic_margin: float, dm_z: float, refit_fit: float):
    """Fit every channel set and variant; returns ``(table, best)`` where ``table`` maps
    ``"missing_input (<channels>, <variant>)"`` to its statistics and ``best`` is ``None``
    or a dict with the fitted :class:`MissingInput`, its statistics and the decision."""
    y, y_nom = np.asarray(y, float), np.asarray(y_nom, float)
    a = np.asarray(model.arx.a, float)
    window = slice(burn, n_fit)
    n = n_fit - burn
    usable, skipped = {}, {}
    for name, w in channels.items():
        c = abs(np.corrcoef(w[:n_fit], y[:n_fit])[0, 1]) if np.std(w[:n_fit]) > 0 else 0.0
        if np.std(w[:n_fit]) == 0:
            skipped[name] = "constant on the fitting segment"
        elif c > SAME_AS_OUTPUT:
            skipped[name] = "the measured output itself (|correlation| > 0.9999)"
        else:
            usable[name] = w
    names = list(usable)
    subsets = [s for r in range(1, min(len(names), 3) + 1)
               for s in itertools.combinations(names, r)]
    G = max(len(subsets) * len(VARIANTS), 1)

    def bic(sse, k, grid=1):
        return n * math.log(max(sse, 1e-300) / n) + k * math.log(n) + 2 * math.log(grid)

    X0 = _design(y_nom, np.zeros((len(y), 0)), a, "input")
    beta0, sse0 = _lstsq(X0, y - y_nom, a, window, criterion)
    y_ref = y_nom + X0 @ beta0
    yh = y[n_fit:]
    fit_nom = rt.fit_percent_unchecked(yh, y_nom[n_fit:])
    ref = {"bic": bic(sse0, 2), "k": 2,
           "fit_sim": rt.fit_percent_unchecked(yh, y_ref[n_fit:])}
    table, best = {}, None
    for subset in subsets:
        W = np.stack([usable[s] for s in subset], axis=1)
        center, scale = W[:n_fit].mean(0), W[:n_fit].std(0)
        w = (W - center) / scale
        for variant in VARIANTS:
            X = _design(y_nom, w, a, variant)
            beta, sse = _lstsq(X, y - y_nom, a, window, criterion)
            y_ext = y_nom + X @ beta
            fit = (rt.fit_percent_unchecked(yh, y_ext[n_fit:]) if np.all(np.isfinite(y_ext))
                   else -np.inf)
            st = {"bic": bic(sse, X.shape[1], G), "k": X.shape[1], "fit_sim": fit}
            table[f"missing_input ({', '.join(subset)}; {variant})"] = st
            if best is None or st["bic"] < best["stats"]["bic"]:
                best = dict(stats=st, subset=subset, variant=variant, beta=beta, y_ext=y_ext,
                            center=center, scale=scale, w=w)
    if best is None:
        return table, None, skipped
    st, y_ext = best["stats"], best["y_ext"]
    r_nom, r_ref, r_ext = yh - y_nom[n_fit:], yh - y_ref[n_fit:], yh - y_ext[n_fit:]
    dm_nom, dm_ref = rt.diebold_mariano(r_nom, r_ext), rt.diebold_mariano(r_ref, r_ext)
    # The same guard as every other finding: a channel that only repairs a nominal free run
    # worse than a constant explains no part of the output.
    dm_const = over_constant(y, n_fit, burn, r_ext)
    st["dm_z_over_constant"] = dm_const
    dbic = ref["bic"] - st["bic"]
    best.update(reference=ref, fit_nominal=fit_nom, dm_vs_nominal=dm_nom, dm_vs_reference=dm_ref,
                dm_over_constant=dm_const, delta_bic_vs_reference=dbic, refit_fit=refit_fit,
                accepted=bool(dbic > bic_margin and dm_nom > dm_z and dm_ref > dm_z
                              and dm_const > dm_z
                              and st["fit_sim"] > max(fit_nom, ref["fit_sim"])))
    best["model"] = _model(model, best, channels_order=best["subset"],
                           signals=np.stack([channels[s] for s in best["subset"]], axis=1))
    resid = (y - y_nom)[burn:n_fit]
    best["correlation"] = {s: _max_lag_corr(resid, usable[s][burn:n_fit]) for s in names}
    return table, best, skipped


def _max_lag_corr(r, w):
    """Largest |correlation| of the residual with the channel at lags 0..LAGS, and its lag."""
    c = rt.correlation(r, w, LAGS)
    k = int(np.argmax(np.abs(c)))
    return {"correlation": float(c[k]), "lag": k}


def _model(model, best, channels_order, signals):
    beta, J = best["beta"], len(channels_order)
    taps, slip = np.zeros((J, LAGS + 1)), np.zeros(J)
    i = 2
    if best["variant"] in ("input", "input+slip"):
        taps = beta[i:i + J * (LAGS + 1)].reshape(J, LAGS + 1)
        i += J * (LAGS + 1)
    if best["variant"] in ("slip", "input+slip"):
        slip = beta[i:i + J]
    f = lambda x: jnp.asarray(np.asarray(x, np.float64))  # noqa: E731
    return MissingInput(model, f(signals), f(best["center"]), f(best["scale"]), f(taps),
                        f(slip), f(beta[0]), f(beta[1]), tuple(channels_order))


def describe(best: dict) -> dict:
    """Physics sentence, where and parameters of an accepted missing input, from its fitted
    values and evidence."""
    subset, variant, m = best["subset"], best["variant"], best["model"]
    corr = best["correlation"]
    main = max(subset, key=lambda s: abs(corr[s]["correlation"]))
    listed = ", ".join(f"'{s}' (residual correlation {corr[s]['correlation']:+.2f} at lag "
                       f"{corr[s]['lag']})" for s in subset)
    how = {"input": f"enters as a second input through the plant's dynamics (FIR of "
                    f"{LAGS + 1} taps over the nominal poles)",
           "slip": "scales the output level (the slip level follows it, as a friction force "
                   "follows a normal force)",
           "input+slip": "both scales the output level and enters as a second input through "
                         "the plant's dynamics"}[variant]
    plural = "channels" if len(subset) > 1 else "channel"
    physics = (f"A missing input: the output follows the recorded {plural} {listed}, which "
               f"the nominal model does not see. Modelled: the {plural} {how}; held-out "
               f"free-run fit {best['fit_nominal']:.1f}% -> {best['stats']['fit_sim']:.1f}%.")
    params = {"channel": main, "channels": list(subset), "variant": variant,
              "gain": float(m.gain), "offset": float(m.offset),
              "taps": {s: np.asarray(m.taps[j]).tolist() for j, s in enumerate(subset)},
              "slip": {s: float(m.slip[j]) for j, s in enumerate(subset)},
              "center": {s: float(m.center[j]) for j, s in enumerate(subset)},
              "scale": {s: float(m.scale[j]) for j, s in enumerate(subset)}}
    where = {"channels": list(subset), "correlation": corr, "regime": "whole record"}
    return {"physics": physics, "where": where, "parameters": params}
