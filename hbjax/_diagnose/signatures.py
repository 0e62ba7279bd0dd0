"""Signatures of the nominal model's mismatch on the fitting segment: the residual tests
(whiteness, independence from past inputs, regime dependence, spectral peaks away from the
input's spectrum) and a Gauss-Newton change-point scan. The candidates start from them."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._misc import chi2_sf
from . import residual_tests as rt


def residual_signatures(v, y, ysim, eps, u, burn):
    e, r = eps[burn:], (y - ysim)[burn:]
    dv = np.sign(np.diff(v[burn - 1:]))
    return {
        "whiteness": rt.whiteness(e),
        "independence": _independence(e, v[burn:], u[burn:]),
        "regime_input": rt.regime_dependence(r, v[burn:]),
        "regime_output": rt.regime_dependence(r, ysim[burn:]),
        "regime_direction": rt.regime_dependence(r, dv),
        "regime_rate": rt.regime_dependence(r, np.abs(np.diff(v[burn - 1:]))),
        "regime_time": rt.regime_dependence(r, np.arange(len(r), dtype=float)),
        "spectral_peaks": [{"frequency": f, "ratio": q} for f, q in
                           rt.spectral_peaks(e, exclude=rt.periodogram(v[burn:]))],
        "simulation_fit": rt.fit_percent_unchecked(y[burn:], ysim[burn:]),
        "noise_std": float(np.std(e)),
    }


def _independence(e, v, u):
    """Independence of the one-step errors from the past recorded inputs ``v`` (as
    :func:`hbjax.resid`) and from the nominal model's internal signal ``u`` (what its
    linear block sees): the smaller p-value, doubled (Bonferroni), with ``"against"``
    naming the signal. Either alone misses a mismatch: ``u`` is constant where the input
    stays inside the nominal model's band, though the recorded output follows the input;
    ``v`` sees a wrong linear block only through the backlash."""
    rows = {"input": rt.independence(e, v), "internal signal": rt.independence(e, u)}
    against, row = min(rows.items(), key=lambda kv: kv[1]["p_value"])
    return {**row, "p_value": min(1.0, 2.0 * row["p_value"]), "against": against}


def independence_after_noise_model(model, v, y, u, burn):
    """:func:`_independence` of a noise-model finding's own one-step errors (its predictor
    whitens the nominal errors): whether the input still predicts what the noise model
    leaves. The nominal errors of a recording whose mismatch is only coloured noise are
    coloured, and a cross-correlation test assuming white errors rejects on them by their
    colour alone; the whitened errors are what the test is calibrated for."""
    e = np.asarray(y) - np.asarray(model.predict_trajectory(jnp.asarray(v), jnp.asarray(y), 0.0))
    return _independence(e[burn:], np.asarray(v)[burn:], np.asarray(u)[burn:])


def change_scan(J, e, burn, grid=100):
    """Gauss-Newton change-point scan: for each candidate time ``tau`` the drop in the
    criterion from letting every base parameter take new values after ``tau`` (linearised
    at the nominal model), in units of the residual variance (about chi2(p) under no
    change)."""
    J, e = np.asarray(J)[burn:], np.asarray(e)[burn:]
    keep = np.any(J != 0, axis=0)
    J = J[:, keep]
    n, p = J.shape
    taus = np.unique(np.linspace(0.05 * n, 0.95 * n, grid).astype(int))
    outer = np.einsum("ti,tj->tij", J, J)
    H2s = np.cumsum(outer[::-1], axis=0)[::-1]
    g2s = np.cumsum((J * e[:, None])[::-1], axis=0)[::-1]
    H, g = H2s[0], g2s[0]
    ridge = 1e-9 * np.trace(H) / p * np.eye(p)
    base = g @ np.linalg.lstsq(H + ridge, g, rcond=None)[0]
    sigma2 = float(np.mean(e**2)) or 1.0
    stats = []
    for tau in taus:
        H2, g2 = H2s[tau], g2s[tau]
        M = np.block([[H, H2], [H2, H2]]) + np.kron(np.eye(2), ridge)
        gg = np.concatenate([g, g2])
        stats.append(float(gg @ np.linalg.lstsq(M, gg, rcond=None)[0] - base) / sigma2)
    stats = np.asarray(stats)
    k = int(np.argmax(stats))
    return {"time": int(taus[k]) + burn, "statistic": float(stats[k]), "dof": int(p),
            "p_value": float(chi2_sf(float(stats[k]), p)), "grid": len(taus)}
