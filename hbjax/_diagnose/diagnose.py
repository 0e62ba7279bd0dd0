"""Mismatch diagnosis: locate where a recording departs from the nominal HB-Hammerstein
model (eq. (10)), name the physics left out, fit it and show the held-out fit improve.

Pipeline (one call of :func:`diagnose`):

1. residual analysis of the nominal model on the fitting segment (whiteness, independence
   from past inputs, regime dependence, spectrum, a change-point scan);
2. every candidate extension of :data:`hbjax.EFFECTS` is started from those signatures and
   fitted jointly with the base parameters (Levenberg-Marquardt through the differentiable
   extended simulator, all candidates in one batched solve);
3. candidates are ranked by BIC on the fitting segment; a mechanism is reported only if it
   beats the plain refit (``parameter_mismatch``) in BIC by a margin *and* improves the
   held-out free-run simulation significantly against the refit and the nominal model
   (Diebold-Mariano tests); the refit is reported only if it beats the nominal model in the
   same way; a one-step-prediction gain alone is at most a noise-model finding;
4. recorded channels offered with the record are tried as a missing input (:mod:`.channels`);
5. the verdict (:mod:`.verdict`): consistent, explained, or structured but unexplained.

The held-out part is chosen so that it is excited as much as the fitting part
(:mod:`.holdout`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._core.cache import ensure_compilation_cache
from .._core.mappings import release_compiled_programs
from .._core.model import Hammerstein
from .._core.precision import require_x64
from .._core.progress import check_progress, progress_bar
from .._identify.recordings import as_input_output
from .._io.recording import Recording
from .._misc import (
    as_float_array,
    check_key,
    check_values,
    fraction,
    no_spread,
    same_length,
)
from .._misc import jsonable as _jsonable
from . import candidates as cands
from . import channels as chan
from . import effects as fx
from . import holdout as ho
from . import verdict as vd
from .clip_nominal import ON_NOMINAL, clip_on_nominal
from .decide import (BIC_MARGIN, DM_Z, decide, order_by_held_out, place_by_free_run, rank,
                     statistics)
from .effects import base_theta, resolve
from .fitting import choose_starts, evaluate_candidates, fit_candidates
from .input_clip_nominal import ON_NOMINAL as INPUT_CLIP_ON_NOMINAL
from .input_clip_nominal import input_clip_on_nominal
from .output_map_nominal import ON_NOMINAL as OUTPUT_MAP_ON_NOMINAL
from .output_map_nominal import output_map_on_nominal
from .kernel import MAX_DELAY
from .level_cascade import ON_NOMINAL as CASCADE
from .level_cascade import level_cascade_on_nominal
from .residual_tests import plateaus
from .result import Diagnosis, Finding
from .signatures import change_scan, independence_after_noise_model, residual_signatures
from .solve import evaluate_batch, jacobian

__all__ = ["Diagnosis", "Finding", "diagnose"]

MAX_STEPS = 45


def _check_inputs(model, v, y, holdout, effects, key):
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    if not model.arx.is_stable():
        # Its free run diverges: every simulation-based statistic would be inf/NaN.
        raise ValueError("the nominal `model` has an unstable A (assumption A3): its free run "
                         "diverges; start from a stable nominal model.")
    v = check_values(as_float_array(v, "v", ndim=1, dtype=jnp.float64), "v")
    y = check_values(as_float_array(y, "y", ndim=1, dtype=jnp.float64), "y", output=True)
    same_length(v=v, y=y)
    holdout = fraction(holdout, "holdout")
    lay_p = model.arx.na + model.arx.nb + 2 * model.backlash.m
    n = int(v.shape[0])
    n_hold = int(round(holdout * n))
    n_fit = n - n_hold
    need_fit = max(100, 10 * (2 * lay_p + 10))
    if n_hold < 50 or n_fit < need_fit:
        raise ValueError(
            f"record too short for `holdout`={holdout}: {n} samples give {n_fit} to fit and "
            f"{n_hold} held out; need at least {need_fit} to fit and 50 held out.")
    if no_spread(np.asarray(v)):
        raise ValueError(
            "`v` is constant: a constant input holds the backlash at one value, so the "
            "recording cannot show the input's effect and a mismatch in it cannot be told "
            "from noise (check that `v` is the input channel).")
    if no_spread(np.asarray(y)):
        raise ValueError(
            f"`y` is constant (every sample {float(y[0]):g}): a recorded output that never "
            "moves shows no dynamics to compare with the nominal model (check that `y` is the "
            "output channel and that the sensor was connected).")
    effects = resolve(effects)
    check_key(key, optional=True)
    return np.asarray(v), np.asarray(y), n_fit, effects


def diagnose(model: Hammerstein, v, y=None, *, holdout: float = 0.3, effects=None, key=None,
             criterion: str = "prediction", progress=True, channels=None,
             split: str = "excited"):
    """Locate, name and model what the nominal ``model`` leaves out of a recording.

    **Arguments:**

    - `model`: the nominal :class:`hbjax.Hammerstein` (what the user believes).
    - `v`, `y`: a recording of the real system (input, output), equal lengths; or one
      :class:`hbjax.Recording` or two-column DataFrame as `v` (then `y` is omitted, and
      the diagnosis figure's time axis is in seconds when the recording's ``dt`` is known).
    - `holdout`: the fraction of the record held out (at its end), never used for fitting;
      every fit figure is measured on it.
    - `split`: ``"excited"`` (default): the held-out part is the last `holdout` fraction
      unless that tail is less excited than the fitting part (input, output or input-rate
      spread below 70% of the fitting part's); then the cut moves earlier (up to half the
      record) until it is excited enough, so that a quiet tail cannot decide, but not to
      where the nominal model's free-run error would lie mostly in the held-out part.
      ``"tail"``: exactly the last `holdout` fraction. ``Diagnosis.split`` reports it.
    - `channels`: other recorded signals, ``{name: array}`` of the record's length (a
      velocity, a normal force, a second actuator...); by default those of a
      :class:`hbjax.Recording` passed as `v`. When a channel explains the residual (enters
      as a second input through the plant's dynamics, or scales the output level) and
      improves the held-out free run significantly, the finding ``missing_input`` names it
      (``parameters["channel"]``).
    - `effects`: names from :data:`hbjax.EFFECTS` and/or :class:`hbjax.AbstractEffect`
      subclasses to consider (default all of :data:`hbjax.EFFECTS`);
      ``parameter_mismatch`` is always included.
    - `key`: unused (the procedure is deterministic); accepted for API symmetry.
    - `criterion`: ``"prediction"`` (default; one-step prediction error, maximum likelihood
      under the paper's white equation error) or ``"simulation"`` (output error, for slow
      processes where one-step prediction hides low-frequency mismatch, e.g. level
      control; ``colored_noise`` and ``parameter_change`` are then not candidates and the
      first 20% of the fitting
      segment, at most 300 samples, is a start-up transient left out of the criterion).
    - `progress`: a progress bar over the stages (nominal model, candidate starts,
      candidate fits, decision) once the diagnosis has run for more than 2 s on a terminal
      or in Jupyter; ``False`` silences it, a dict passes options to tqdm.

    **Returns:** a :class:`Diagnosis`; its ``verdict`` is ``"consistent"``,
    ``"explained"`` or ``"unexplained"`` (see :class:`Diagnosis`). A mechanism is reported
    only if it improves the held-out free-run simulation significantly; a gain in one-step
    prediction alone is at most a noise-model finding (``colored_noise``).
    """
    require_x64("diagnose")
    ensure_compilation_cache()
    release_compiled_programs()
    check_progress(progress)
    if channels is None:
        channels = getattr(v, "channels", None) or None
    t0 = float(getattr(v, "t0", 0.0) or 0.0) if isinstance(v, Recording) else 0.0
    v, y, dt = as_input_output(v, y)
    with progress_bar(progress, total=4, desc="diagnose", unit="stage", live=True) as bar:
        found = _diagnose(model, v, y, holdout, effects, key, criterion, bar, channels, split)
    return dataclasses.replace(found, dt=dt, t0=t0)


def _diagnose(model, v, y, holdout, effects, key, criterion, bar, channels=None,
              split="excited"):
    v, y, n_fit, effects = _check_inputs(model, v, y, holdout, effects, key)
    if criterion not in ("prediction", "simulation"):
        raise ValueError(f"`criterion` must be 'prediction' or 'simulation', got {criterion!r}.")
    if split not in ("excited", "tail"):
        raise ValueError(f"`split` must be 'excited' or 'tail', got {split!r}.")
    channels = chan.check_channels(channels, len(v))
    p_base = model.arx.na + model.arx.nb + 2 * model.backlash.m
    lay, theta_nom = base_theta(model)
    # 1. Nominal behaviour over the whole record (its free run also places the split).
    consts0 = jnp.asarray([max(float(np.max(np.abs(v))), 1e-12), 0.0, 1.0, 1.0])
    _, eps_nom, ysim_nom, u_nom = (np.asarray(a[0]) for a in evaluate_batch(
        lay, theta_nom[None], jnp.asarray(cands._ints())[None], consts0, v, y))
    burn = lay.na + lay.nb + MAX_DELAY + 4
    # where the nominal model misses (its free-run error), so a move of the cut cannot take
    # the mismatch out of the fitting part; the start-up samples are left out
    free_run_error = np.where(np.arange(len(y)) < burn, np.nan, y - ysim_nom)
    n_fit, split_report = ho.choose_split(v, ysim_nom, holdout,
                                          min_fit=max(100, 10 * (2 * p_base + 10)), mode=split,
                                          error=free_run_error)
    if criterion == "simulation":
        # no noise model in an output-error fit, and the change model's criterion is only
        # an approximation of the output error after the change
        effects = [e for e in effects if e.name not in ("colored_noise", "parameter_change")]
        burn = max(burn, min(n_fit // 5, 300))
    v_fit, y_fit = v[:n_fit], y[:n_fit]
    T = len(v)
    K = 2 * lay.p_base

    # The fitting segment: its constants, Jacobian and residual tests.
    du = np.abs(np.diff(u_nom[:n_fit]))
    width = 0.1 * float(np.median(du[du > 1e-12 * (np.max(du) + 1e-300)])) if np.any(du > 0) else 1.0
    consts = jnp.asarray([float(consts0[0]), float(np.mean(y_fit)),
                          max(float(np.std(y_fit)), 1e-12), max(width, 1e-12)])
    S_base = cands.base_selection(lay, theta_nom, K)
    e_j, J = jacobian(lay, theta_nom, jnp.asarray(S_base), jnp.asarray(cands._ints()), consts,
                      v_fit, y_fit, burn, criterion)
    tests = residual_signatures(v_fit, y_fit, ysim_nom[:n_fit], eps_nom[:n_fit], u_nom[:n_fit], burn)
    tests["change_scan"] = change_scan(J, e_j, burn)
    ctx = cands.Context(lay, theta_nom, consts, v_fit, y_fit, ysim_nom[:n_fit], u_nom[:n_fit],
                        eps_nom[:n_fit], burn, tests["change_scan"], v_record=v)

    bar.update(1)
    # 2. Candidates: choose each start by a batched criterion evaluation, then fit all.
    candidates = cands.build(ctx, effects)
    theta0, ints = choose_starts(ctx, candidates, v_fit, y_fit, criterion)
    bar.update(1)
    theta_fit, steps, ok = fit_candidates(ctx, candidates, theta0, ints, v_fit, y_fit, criterion,
                                          MAX_STEPS)

    bar.update(1)
    # 3. Whole-record evaluation of nominal + every fitted candidate, then the decision.
    all_ints = jnp.asarray(np.stack([cands._ints()] + ints))
    fast_all, eps_all, ysim_all, u_all = evaluate_candidates(ctx, candidates, theta_fit, all_ints,
                                                             v, y, criterion)
    stats = statistics(y, fast_all, eps_all, ysim_all, n_fit, burn, lay, candidates, theta_fit)
    failed = {}
    for i, (c, st, s_, o) in enumerate(zip(candidates, stats[1:], np.asarray(steps),
                                           np.asarray(ok))):
        st["lm_steps"], st["lm_converged"] = int(s_), bool(o)
        why = vd.failure(st, theta_fit[i], c.params if c.generic else None)
        if why is not None:
            failed[c.label] = f"{why} ({int(s_)} solver steps)"
            st["bic"] = np.inf  # never ranked or reported
            st["decision"] = "failed: " + why
    free_runs = {}  # the kernel's free run of each finding, reused to order them
    findings = decide(ctx, candidates, stats, theta_fit, np.asarray(all_ints), eps_all, ysim_all,
                       u_all, y, v, n_fit, tests, free_runs)
    table = {c.label: {k: stats[i + 1].get(k) for k in
                        ("bic", "k", "sse", "fit_sim", "fit_pred", "lm_steps", "lm_converged",
                         "dbic", "dm_z", "dm_z_simulation", "dm_z_over_constant", "base_p",
                         "decision")}
             for i, c in enumerate(candidates)}
    table["nominal"] = {k: stats[0][k] for k in ("bic", "k", "sse", "fit_sim", "fit_pred")}
    if fx.OutputSaturation in effects and not any(f.effect == "output_saturation"
                                                    for f in findings):
        row, finding = clip_on_nominal(ctx, model, y, v, n_fit, burn, ysim_all, u_all, stats,
                                        [c.label for c in candidates], criterion, tests)
        if row is not None:
            table[ON_NOMINAL] = row
        if finding is not None:
            findings = findings + [finding]
    if channels:
        finding = _missing_input(model, y, ysim_all, stats, [c.label for c in candidates],
                                 channels, n_fit, burn, criterion, table)
        if finding is not None:
            findings = findings + [finding]
    if fx.InputSaturation in effects and not any(f.mechanism for f in findings):
        # an actuator limit the held-out part alone cannot confirm: validated by folds
        row, finding = input_clip_on_nominal(ctx, model, y, v, n_fit, burn, ysim_all, u_all,
                                             stats, [c.label for c in candidates], criterion)
        if row is not None:
            table[INPUT_CLIP_ON_NOMINAL] = row
        if finding is not None:
            findings = findings + [finding]
    if fx.OutputNonlinearity in effects and not any(f.mechanism for f in findings):
        # a sensor curvature the held-out part alone cannot confirm (quiet, or at levels
        # the fitting segment never reached): validated by folds
        row, finding = output_map_on_nominal(ctx, model, y, v, n_fit, burn, ysim_all, u_all,
                                             stats, [c.label for c in candidates])
        if row is not None:
            table[OUTPUT_MAP_ON_NOMINAL] = row
        if finding is not None:
            findings = findings + [finding]
    if fx.LevelDependentDynamics in effects:
        # a level fed through a second, unmeasured one: the level law of a cascade of
        # tanks, which the single-level law cannot express; an output-error model of a
        # slow process under either criterion (placed by the held-out free run below where
        # its BIC is not on the criterion of the others')
        sensor = (plateaus(y, -1), plateaus(y, +1))
        found = next((f for f in rank(findings) if f.mechanism), None)
        row, finding = level_cascade_on_nominal(model, y, v, n_fit, burn, ysim_all, u_all,
                                                stats, [c.label for c in candidates], tests,
                                                sensor, found)
        if row is not None:
            table[CASCADE] = row
        if finding is not None:
            findings = findings + [finding]
    findings = order_by_held_out(
        place_by_free_run(rank(findings), criterion, v, y, n_fit, free_runs),
        v, y, n_fit, free_runs)
    if findings and not any(f.mechanism for f in findings):
        # A noise model alone explains coloured errors, not errors the input predicts.
        tests["independence_after_noise_model"] = independence_after_noise_model(
            findings[0].model, v_fit, y_fit, u_nom[:n_fit], burn)
    verdict, detail = vd.verdict(findings, tests)
    tests["unexplained_structure"] = verdict == "unexplained"
    bar.update(1)
    return Diagnosis(verdict != "consistent", findings, _jsonable(tests), _jsonable(table),
                     n_fit, T - n_fit, model, v, y, verdict=verdict,
                     unexplained=_jsonable(detail) if verdict == "unexplained" else {},
                     failed=failed, split=_jsonable(split_report))


def _missing_input(model, y, ysim_all, stats, names, channels, n_fit, burn, criterion, table):
    """The ``missing_input`` finding (or ``None``) from the offered recorded channels; its
    rows go into the candidate ``table``."""
    ref_i = names.index("parameter_mismatch") + 1
    rows, best, skipped = chan.fit_missing_input(
        model, y, np.asarray(ysim_all[0]), channels, n_fit, burn, criterion, BIC_MARGIN, DM_Z,
        float(stats[ref_i]["fit_sim"]))
    table.update(rows)
    for name, why in skipped.items():
        table[f"missing_input ({name})"] = {"decision": "skipped: " + why}
    if best is None or not best["accepted"]:
        return None
    text = chan.describe(best)
    evidence = {
        "reference": "nominal", "variant": f"channels on the nominal model ({best['variant']})",
        "bic": best["stats"]["bic"], "parameters_fitted": best["stats"]["k"],
        "delta_bic_vs_nominal": stats[0]["bic"] - best["stats"]["bic"],
        "delta_bic_vs_refit": stats[ref_i]["bic"] - best["stats"]["bic"],
        "delta_bic_vs_no_channel": best["delta_bic_vs_reference"],
        "dm_z": best["dm_vs_nominal"], "dm_z_vs_no_channel": best["dm_vs_reference"],
        "dm_z_over_constant": best["dm_over_constant"],
        "no_channel_fit": best["reference"]["fit_sim"], "refit_fit": best["refit_fit"],
        "reference_fit": best["fit_nominal"], "residual_correlation": best["correlation"],
    }
    return Finding(effect="missing_input", physics=text["physics"], where=_jsonable(text["where"]),
                   parameters=_jsonable(text["parameters"]), model=best["model"],
                   metric="simulation", fit_before=float(best["fit_nominal"]),
                   fit_after=float(best["stats"]["fit_sim"]), evidence=_jsonable(evidence))
