"""Plain-language reports for diagnosed effects: the physics sentence, where the mismatch
lives (time windows, regimes) and the physical parameters of the fitted extension."""

from __future__ import annotations

import math

import numpy as np

from .residual_tests import plateaus, windows


def _f(x, digits=4):
    return float(f"{float(x):.{digits}g}")


def _effect_windows(info, mask=None):
    """Where the extension changes the simulated output materially (or ``mask``)."""
    y, ys, yr = info["y"], info["ysim"], info["ysim_ref"]
    if mask is None:
        diff = np.abs(ys - yr)
        scale = float(np.sqrt(np.mean((y - ys) ** 2))) or 1.0
        mask = diff > 0.5 * scale
    return windows(mask, min_gap=max(5, len(y) // 200))


def describe(effect, model, ctx, info) -> dict:
    fn = globals()[f"_{effect}"]
    return fn(model, ctx, info)


def _parameter_mismatch(model, ctx, info):
    lay = ctx.lay
    nom = np.asarray(ctx.theta_nom[:lay.p_base])
    new = np.concatenate([np.asarray(x) for x in (model.arx.a, model.arx.b,
                                                   model.backlash.c1, model.backlash.c2)])
    rel = np.abs(new - nom) / np.maximum(np.abs(nom), 1e-3 * (np.max(np.abs(nom)) or 1.0))
    k = int(np.argmax(rel))
    from .._core.params import param_names

    name = param_names(model)[k]
    return {
        "physics": ("The structure is right but the parameters are off: re-identifying the "
                    f"same model explains the mismatch (largest change in {name}: "
                    f"{_f(nom[k])} -> {_f(new[k])})."),
        "where": {"windows": [[0, len(info["y"])]], "regime": "whole record"},
        "parameters": {"a": model.arx.a, "b": model.arx.b, "c1": model.backlash.c1,
                       "c2": model.backlash.c2, "largest_relative_change": {name: _f(rel[k])}},
    }


def _saturation_report(model, info, signal, what):
    lo = None if model.lower is None else float(model.lower)
    hi = None if model.upper is None else float(model.upper)
    low_mask = signal <= lo + 1e-9 * (abs(lo) + 1) if lo is not None else np.zeros(len(signal), bool)
    high_mask = signal >= hi - 1e-9 * (abs(hi) + 1) if hi is not None else np.zeros(len(signal), bool)
    frac = float(np.mean(low_mask | high_mask))
    sides = " and ".join(s for s in (f"below at {_f(lo)}" if lo is not None else "",
                                     f"above at {_f(hi)}" if hi is not None else "") if s)
    return lo, hi, low_mask | high_mask, frac, sides


def _output_saturation(model, ctx, info):
    lo, hi, mask, frac, sides = _saturation_report(model, info, info["ysim"], "output")
    y = np.asarray(info["y"])
    where = {"windows": windows(mask, min_gap=5), "output_range": [lo, hi],
             "regime": "output at its limit"}
    evidence = {}
    # where the measurement itself sits exactly at its extreme (model-free): the clipped
    # windows proper; the model's clip mask is kept as `model_windows`
    stuck = []
    for side, s, level in (("lower", -1, lo), ("upper", 1, hi)):
        sig = plateaus(y, s) if level is not None else None
        if sig is not None and abs(sig["level"] - level) <= 0.1 * max(abs(level), 1e-12):
            stuck += sig["windows"]
            where[f"stuck_at_{side}"] = {"level": sig["level"], "samples": sig["samples"]}
            evidence[f"samples_at_{side}_level"] = sig["samples"]
    if stuck:
        where["model_windows"] = where["windows"]
        where["windows"] = sorted(stuck)
    evidence.setdefault("samples_at_upper_level", 0)
    return {
        "physics": (f"The measured output is clipped {sides}: a sensor range, ADC or overflow "
                    f"limit the nominal model does not have ({100 * frac:.1f}% of samples)."),
        "where": where,
        "parameters": {"lower": lo, "upper": hi, "clipped_fraction": frac},
        "evidence": evidence,
    }


def _input_saturation(model, ctx, info):
    from .._core.model import play_trajectory

    u = np.asarray(play_trajectory(model.base.backlash, np.asarray(info["v"]), 0.0))
    lo, hi, mask, frac, sides = _saturation_report(model, info, u, "input")
    return {
        "physics": (f"The internal signal u (actuator effort after the backlash) is limited "
                    f"{sides}: an actuator saturation upstream of the dynamics "
                    f"({100 * frac:.1f}% of samples)."),
        "where": {"windows": windows(mask, min_gap=5), "internal_range": [lo, hi],
                  "regime": "large |u| (actuator at its limit)"},
        "parameters": {"lower": lo, "upper": hi, "clipped_fraction": frac},
    }


def _extra_delay(model, ctx, info):
    return {
        "physics": (f"The output responds {model.delay} sample(s) later than the model "
                    "predicts: extra transport delay (dead time, communication or sampling lag)."),
        "where": {"windows": [[0, len(info["y"])]], "regime": "every input change"},
        "parameters": {"delay": int(model.delay)},
    }


def _unmodeled_dynamics(model, ctx, info):
    a = np.concatenate([[1.0], np.asarray(model.base.arx.a), [float(model.a_extra)]])
    b = np.concatenate([np.asarray(model.base.arx.b), [float(model.b_extra)]])
    poles = np.roots(a)
    zeros = np.roots(b) if np.any(b[1:] != 0) else np.array([])
    return {
        "physics": ("The linear block needs one more pole and zero than the model has: "
                    "unmodelled dynamics (a sensor/actuator lag or a compliant mode)."),
        "where": {"windows": _effect_windows(info), "regime": "transients after input changes"},
        "parameters": {"a_extra": _f(model.a_extra), "b_extra": _f(model.b_extra),
                       "poles": [[_f(p.real), _f(p.imag)] for p in poles],
                       "zeros": [[_f(z.real), _f(z.imag)] for z in zeros]},
    }


def _colored_noise(model, ctx, info):
    d = np.asarray(model.d)
    roots = np.roots(np.concatenate([[1.0], d]))
    return {
        "physics": ("The disturbance is not white equation error: it is correlated in time "
                    "(coloured noise), so a noise model D improves prediction but not simulation."),
        "where": {"windows": [[0, len(info["y"])]], "regime": "whole record (disturbance spectrum)"},
        "parameters": {"d": d, "noise_poles": [[_f(r.real), _f(r.imag)] for r in roots]},
    }


def _offset_drift(model, ctx, info):
    n = len(info["y"])
    rate = float(model.rate)
    return {
        "physics": (f"The output drifts slowly by {_f(rate * n)} over the record "
                    "(sensor or thermal drift) on top of what the input explains."),
        "where": {"windows": [[0, n]], "regime": "grows with time"},
        "parameters": {"offset": _f(model.offset), "rate": rate, "drift_over_record": _f(rate * n)},
    }


def _parameter_change(model, ctx, info):
    n = len(info["y"])
    t = int(model.time)
    before, after = model.base, model.after()
    g0 = float(np.sum(before.arx.b) / (1 + np.sum(before.arx.a)))
    g1 = float(np.sum(after.arx.b) / (1 + np.sum(after.arx.a)))
    return {
        "physics": (f"The system changed abruptly at sample {t} ({100 * t / n:.0f}% of the "
                    f"record): wear, a fault or a load change (static gain {_f(g0)} -> {_f(g1)})."),
        "where": {"windows": [[t, n]], "change_time": t, "regime": "after the change"},
        "parameters": {"time": t, "time_fraction": t / n, "gain_before": g0, "gain_after": g1,
                       "da": model.da, "db": model.db, "dc1": model.dc1, "dc2": model.dc2},
        "evidence": {"change_scan": info["tests"]["change_scan"]},
    }


def _periodic_disturbance(model, ctx, info):
    f = float(model.frequency)
    amp = math.hypot(float(model.cos_amp), float(model.sin_amp))
    phase = math.atan2(-float(model.sin_amp), float(model.cos_amp))
    return {
        "physics": (f"An additive sinusoid of amplitude {_f(amp)} at {_f(f)} cycles/sample "
                    f"(period {_f(1 / f if f else np.inf)} samples) unrelated to the input: "
                    "mains hum, a rotating part or vibration."),
        "where": {"windows": [[0, len(info["y"])]], "frequency": f,
                  "regime": "whole record, narrow band"},
        "parameters": {"frequency": f, "amplitude": amp, "phase": phase,
                       "period_samples": 1 / f if f else None},
    }


def _output_nonlinearity(model, ctx, info):
    ys = info["ysim"]
    z = np.linspace(-2, 2, 9)
    bend = float(model.scale) * (float(model.k2) * z**2 + float(model.k3) * z**3)
    worst = float(model.center + model.scale * z[int(np.argmax(np.abs(bend)))])
    return {
        "physics": ("The output depends nonlinearly on the linear block's output (sensor "
                    f"curvature): up to {_f(np.max(np.abs(bend)))} off a straight line, most "
                    f"near output {_f(worst)}."),
        "where": {"windows": _effect_windows(info), "output_range": [float(ys.min()), float(ys.max())],
                  "regime": f"output far from {_f(model.center)}"},
        "parameters": {"k2": _f(model.k2), "k3": _f(model.k3), "center": model.center,
                       "scale": model.scale, "max_deviation": _f(np.max(np.abs(bend)))},
    }


def _coulomb_friction(model, ctx, info):
    u = info["u"]
    du = np.diff(u, prepend=u[0])
    moving = np.abs(du) > model.width
    return {
        "physics": (f"A force of about {_f(abs(float(model.force)))} that only depends on the "
                    "direction of motion of the driven side: dry (Coulomb) friction, flat while "
                    "sliding and switching sign at each reversal."),
        "where": {"windows": windows(moving, min_gap=5), "regime":
                  "while the driven side moves (sign of du)",
                  "moving_fraction": float(np.mean(moving))},
        "parameters": {"force": _f(model.force), "width": model.width},
    }


def _branch_degree(model, ctx, info):
    m = model.base.backlash.m
    c1 = float(model.c1_extra) / model.scale**m
    c2 = float(model.c2_extra) / model.scale**m
    v = info["v"]
    return {
        "physics": (f"The backlash branches are curved beyond degree {m - 1}: a degree-{m} term "
                    "(stiffening or softening of the transmission at large input) is missing."),
        "where": {"windows": _effect_windows(info), "input_range": [float(v.min()), float(v.max())],
                  "regime": "large |v|"},
        "parameters": {"degree": m, "c1_extra": c1, "c2_extra": c2},
    }
