"""The decision among fitted candidates: BIC on the fitting segment (the criterion that was
minimised) against the nested reference, confirmed on the held-out part by Diebold-Mariano
tests of the free-run simulation error (eqs. (10) extended by each effect)."""

from __future__ import annotations

import math

import numpy as np

from .._misc import chi2_sf
from .._misc import jsonable as _jsonable
from . import candidates as cands
from . import residual_tests as rt
from .effect_base import ANCHORED
from .result import Finding

#: BIC margin a candidate must win by ("very strong" evidence on the Kass-Raftery scale)
BIC_MARGIN = 10.0
#: z of the held-out Diebold-Mariano test a candidate must reach
DM_Z = 2.0
#: level of the likelihood-ratio test that rejects an anchored variant's nominal base
ANCHOR_ALPHA = 1e-3
_PREDICTION_METRIC = ("colored_noise",)


def rank(findings):
    """The order of the reported findings (``Diagnosis.findings``; the first is ``best``):
    mechanisms before noise-model findings, each group by BIC on the fitting segment; then
    a finding whose recording shows its effect's own model-free signature
    (``evidence["record_signature"]``, e.g. an output held exactly at a level for runs of
    samples) moves ahead of the rivals its class names (``signature_rivals``): effects that
    can mimic its residual, and so may win in BIC, but cannot produce that signature."""
    out = sorted(findings, key=lambda f: (not f.mechanism, f.evidence["bic"]))
    for f in [f for f in out if f.evidence.get("record_signature")]:
        rivals = getattr(type(f.model), "signature_rivals", ())
        i = next(k for k, g in enumerate(out) if g is f)
        # a rival whose own model reproduces the signature (a level law read through the
        # sensor's range) keeps its place
        first = next((k for k, g in enumerate(out[:i]) if g.effect in rivals
                      and not g.evidence.get("record_signature")), None)
        if first is not None:
            out.insert(first, out.pop(i))
    return out


def held_out_free_run_errors(v, y, n_fit, free_runs=None):
    """``error(finding)``: the held-out free-run error of a finding's model, cached per
    finding. ``free_runs`` maps ``id(finding)`` to the free run the kernel already
    simulated for it (the candidates' ``ysim_all`` rows: equal to :func:`simulate`'s to
    rounding, 3e-16 of the output's range where measured); other findings (fitted outside
    the kernel) are simulated here, one compilation per model class."""
    from .._core.simulate import simulate

    known = free_runs or {}
    errors = {}

    def error(g):
        if id(g) not in errors:
            y_sim = known[id(g)] if id(g) in known else simulate(g.model, v)
            errors[id(g)] = (y - np.asarray(y_sim))[n_fit:]
        return errors[id(g)]

    return error


def place_by_free_run(findings, criterion, v, y, n_fit, free_runs=None):
    """A finding whose BIC is on another criterion than ``criterion`` (its
    ``evidence["bic_criterion"]``: the two-store level law, fitted by output error, when the
    diagnosis runs on one-step prediction) cannot be placed among the mechanisms by BIC: it
    goes after the last mechanism, then moves ahead of each mechanism just before it whose
    held-out free run it simulates significantly better (Diebold-Mariano z > DM_Z on the
    held-out free-run errors), the evidence every mechanism is reported on."""
    held_out_error = held_out_free_run_errors(v, y, n_fit, free_runs)
    out = list(findings)
    for f in [f for f in out if f.evidence.get("bic_criterion", criterion) != criterion]:
        out.remove(f)
        i = sum(g.mechanism for g in out)  # mechanisms come first (rank)
        out.insert(i, f)
        r_f = held_out_error(f)
        while i > 0 and np.all(np.isfinite(r_f)):
            r_g = held_out_error(out[i - 1])
            if np.all(np.isfinite(r_g)) and not rt.diebold_mariano(r_g, r_f) > DM_Z:
                break
            out[i - 1], out[i] = out[i], out[i - 1]
            i -= 1
    return out


def order_by_held_out(findings, v, y, n_fit, free_runs=None):
    """The mechanisms of ``findings`` (ranked by :func:`rank`, mechanisms first) with each
    moved ahead of the one just before it while it simulates the held-out part
    significantly better (Diebold-Mariano z > DM_Z on the held-out free-run errors): the
    evidence every mechanism is reported on also orders them. BIC on the fitting segment
    alone ranked a two-parameter effect on the held nominal base (a curved branch) ahead
    of the refit on a record of mismatched parameters, where the refit simulated the
    held-out part better at z = 4.4. A finding whose recording shows its own signature
    (``evidence["record_signature"]``) is not overtaken by the rivals its class names
    (``signature_rivals``: effects that can mimic its residual but not that signature).
    ``free_runs``: see :func:`held_out_free_run_errors`."""
    out = list(findings)
    held_out_error = held_out_free_run_errors(v, y, n_fit, free_runs)

    for k in range(1, sum(f.mechanism for f in out)):
        i = k
        while i > 0:
            ahead, f = out[i - 1], out[i]
            if (ahead.evidence.get("record_signature")
                    and f.effect in getattr(type(ahead.model), "signature_rivals", ())):
                break
            r_ahead, r_f = held_out_error(ahead), held_out_error(f)
            if not (np.all(np.isfinite(r_ahead)) and np.all(np.isfinite(r_f))
                    and rt.diebold_mariano(r_ahead, r_f) > DM_Z):
                break
            out[i - 1], out[i] = f, ahead
            i -= 1
    return out


def statistics(y, fast_all, eps_all, ysim_all, n_fit, burn, lay, candidates, theta_fit):
    """BIC on the fitting segment (the criterion that was minimised) and held-out fits
    (exact simulator and predictor)."""
    n = n_fit - burn
    out = []
    for i in range(eps_all.shape[0]):
        e = eps_all[i]
        sse = float(np.sum(fast_all[i][burn:n_fit] ** 2))
        finite = math.isfinite(sse) and np.all(np.isfinite(ysim_all[i]))
        fit = rt.fit_percent_unchecked
        if i == 0:
            k, grid = 0, 1
        else:
            c = candidates[i - 1]
            k, grid = cands.n_free(lay, c, np.asarray(theta_fit[i - 1])), c.grid
        bic = n * math.log(max(sse, 1e-300) / n) + k * math.log(n) + 2 * math.log(grid) \
            if finite else np.inf
        yh = y[n_fit:]
        out.append({
            "bic": bic, "k": k, "sse": sse,
            "fit_sim": fit(yh, ysim_all[i][n_fit:]) if finite else -np.inf,
            "fit_pred": fit(yh, yh - e[n_fit:]) if finite else -np.inf,
        })
    return out


def over_constant(y, n_fit, burn, error) -> float:
    """Diebold-Mariano z that the held-out ``error`` is smaller than that of a constant
    output, the fitting part's mean. A model that does not beat this explains no part of
    the output, whatever it gains on a nominal model that is worse than a constant (on an
    output unrelated to the input, a clip that held the nominal free run near the mean
    lifted the held-out fit from -196% to 0% and was reported as the explanation)."""
    y = np.asarray(y, float)
    return rt.diebold_mariano(y[n_fit:] - np.mean(y[burn:n_fit]), np.asarray(error, float))


def _margin_over_noise_rival(c, st, stats, names, dm, dm_pred, against, nom, dm_sim_nom):
    """For a mechanism whose held-out free-run gain is not significant (nor its free run
    significantly worse than its reference's, ``dm``, or than the nominal model's,
    ``dm_sim_nom``) but whose one-step prediction gain is: its BIC margin over the noise
    model that could mimic that gain (``noise_rival`` of its class) if that margin exceeds
    BIC_MARGIN, else ``None``. Both free-run conditions: a refit whose own free run is far
    off (a held-out fit of -8 % against the nominal model's 90 %) is no guard, and an
    extra lag that then simulated at 64 % was reported on a record of coloured noise."""
    rival = c.cls.noise_rival
    if rival is not None and c.anchored:
        rival = rival + ANCHORED
    if rival is None or rival not in names:
        return None
    margin = stats[names.index(rival) + 1]["bic"] - st["bic"]
    if (dm_pred > DM_Z and dm > -DM_Z and dm_sim_nom > -DM_Z
            and st["fit_pred"] > against["fit_pred"]
            and st["fit_pred"] > nom["fit_pred"] and math.isfinite(margin)
            and margin > BIC_MARGIN):
        return margin
    return None


def _base_consistency(c, st, stats, names, n):
    """For an anchored candidate: the p-value of the likelihood-ratio test of its nominal
    base against the same effect with the base refitted, ``n ln(SSE_held / SSE_free)``
    about chi2 with as many degrees of freedom as base parameters were freed (``None``
    when not anchored or the refitted variant failed).

    An anchored variant says "the nominal model is right apart from this effect"; where
    the data reject that (the base must move as well), the effect alone is not the
    explanation, however few parameters it has: a small mismatch of many base parameters
    is mimicked in part by a two-parameter effect, which then wins in BIC against a refit
    that pays for every base parameter."""
    if not c.anchored or c.effect not in names:
        return None
    free = stats[names.index(c.effect) + 1]
    df = free["k"] - st["k"]
    if df <= 0 or not (math.isfinite(free["bic"]) and free["sse"] > 0):
        return None
    lr = max(n * math.log(st["sse"] / free["sse"]), 0.0)
    return float(chi2_sf(lr, df))


def decide(ctx, candidates, stats, theta_fit, ints, eps_all, ysim_all, u_all, y, v, n_fit, tests,
           free_runs=None):
    """The findings among the fitted candidates (most supported first); every candidate's
    ``stats`` row gets its ``decision``; ``free_runs`` (a dict), if given, receives each
    finding's free run over the record by ``id(finding)`` (its ``ysim_all`` row).

    A **mechanism** is reported only if it improves the held-out *free-run simulation*:
    it beats its reference (the refit ``parameter_mismatch``; for the refit, and for every
    candidate when the refit's linear block is unstable, the nominal model) by more than
    BIC_MARGIN on the fitting segment, its held-out simulation error
    is significantly smaller than both the reference's and the nominal model's
    (Diebold-Mariano z > DM_Z each), and its held-out simulation fit is above both. Every
    finding must also beat a constant output on the held-out part (:func:`over_constant`,
    z > DM_Z, in its own metric): a nominal model worse than a constant is improved by
    anything that flattens it, and that explains nothing. A gain
    in one-step prediction alone is at most a noise-model finding: only ``colored_noise``
    (a noise model, no mechanism) is judged on held-out prediction, and its free run must
    not be significantly worse than that of the model it extends (its reference, the
    refit): a noise model changes no mechanism, so it must not cost free-run accuracy, but
    the base estimation it shares with the refit may (on a record of the nominal model
    itself, every refit simulates slightly worse than the nominal model). One exception
    (:func:`_margin_over_noise_rival`): a mechanism whose class names a ``noise_rival`` is
    reported on a significant held-out prediction gain alone where it beats that noise
    model by BIC_MARGIN, and its finding's metric is then ``"prediction"``."""
    names = [c.label for c in candidates]
    nom = stats[0]
    ref_i = names.index("parameter_mismatch") + 1
    ref = stats[ref_i]
    # A refit whose linear block is unstable (assumption A3) is no reference: its free run
    # diverges, and a test against held-out errors of 1e27 says nothing (a harmonic
    # distortion that lifted the held-out fit from 87.5% to 97.1% failed its Diebold-
    # Mariano test against such a refit, z = 1.9). Every candidate is then judged
    # against the nominal model.
    theta_ref = np.asarray(theta_fit[ref_i - 1])
    refit_stable = bool(np.all(np.isfinite(theta_ref[:ctx.lay.p_base]))
                        and cands.base_model(ctx.lay, theta_ref).arx.is_stable())
    yh = y[n_fit:]

    def held(k, metric):
        return eps_all[k][n_fit:] if metric == "prediction" else yh - ysim_all[k][n_fit:]

    findings = []
    for i, c in enumerate(candidates, start=1):
        st = stats[i]
        if not math.isfinite(st["bic"]):
            st.setdefault("decision", "failed: non-finite criterion")
            continue
        # The refit and the anchored variants (base held at the nominal values) change
        # the nominal model in one way each: their reference is the nominal model.
        against, j = ((nom, 0) if c.effect == "parameter_mismatch" or c.anchored
                      or not refit_stable else (ref, ref_i))
        noise_model = c.effect in _PREDICTION_METRIC
        metric = "prediction" if noise_model else "simulation"
        key = "fit_pred" if noise_model else "fit_sim"
        dm = rt.diebold_mariano(held(j, metric), held(i, metric))
        dm_sim_nom = rt.diebold_mariano(held(0, "simulation"), held(i, "simulation"))
        dm_pred = rt.diebold_mariano(held(j, "prediction"), held(i, "prediction"))
        dm_sim_ref = (rt.diebold_mariano(held(j, "simulation"), held(i, "simulation"))
                      if noise_model else dm)
        dbic = against["bic"] - st["bic"]
        rival_margin = None
        st.update(dbic=dbic, dm_z=dm, dm_z_simulation=dm_sim_nom)
        base_p = _base_consistency(c, st, stats, names, n_fit - ctx.burn)
        if base_p is not None:
            st["base_p"] = base_p
        if dbic <= BIC_MARGIN:
            why = f"BIC gain over its reference {dbic:.1f} <= {BIC_MARGIN:g}"
        elif base_p is not None and base_p < ANCHOR_ALPHA:
            why = (f"the nominal base is rejected with this effect (likelihood ratio against "
                   f"the variant with the base refitted, p = {base_p:.2g} < {ANCHOR_ALPHA:g})")
        elif noise_model and not (dm > DM_Z and st[key] > against[key] and st[key] > nom[key]):
            why = "no significant held-out one-step-prediction gain"
        elif noise_model and dm_sim_ref < -DM_Z:
            why = "free run significantly worse than that of the model it extends"
        elif not noise_model and not (dm > DM_Z and dm_sim_nom > DM_Z and st[key] > against[key]
                                      and st[key] > nom[key]):
            rival_margin = _margin_over_noise_rival(c, st, stats, names, dm, dm_pred, against,
                                                    nom, dm_sim_nom)
            if rival_margin is not None:
                metric, key = "prediction", "fit_pred"
                why = None
            else:
                why = ("prediction-only gain: at most a noise-model finding"
                       if dm_pred > DM_Z else "no significant held-out free-run gain")
        else:
            # No separate rule pits unmodeled_dynamics against colored_noise: an ARX block
            # one order up can absorb AR-coloured equation error in BIC, but a noise model
            # cannot give the held-out free-run gain the mechanism has just shown. A rule
            # that also demanded a BIC margin over colored_noise fired on 34 of 464
            # independent cases: it refused 3 true unmodeled_dynamics and changed no
            # colored_noise case and no clean record (benchmarks/RESULTS.md).
            why = None
        if why is None:
            dm_const = over_constant(y, n_fit, ctx.burn, held(i, metric))
            st["dm_z_over_constant"] = dm_const
            if not dm_const > DM_Z:
                why = (f"held-out {metric} not significantly better than a constant output "
                       f"(Diebold-Mariano z {dm_const:.2f} <= {DM_Z:g}): it explains no part "
                       f"of the output")
        st["decision"] = why or "reported"
        if why is not None:
            continue
        evidence = {
            "refit_stable": bool(refit_stable),
            "delta_bic_vs_refit": ref["bic"] - st["bic"],
            "delta_bic_vs_nominal": nom["bic"] - st["bic"],
            "dm_z": dm, "dm_z_simulation_vs_nominal": dm_sim_nom,
            "dm_z_over_constant": st["dm_z_over_constant"],
            "reference": "nominal" if j == 0 else "parameter_mismatch",
            "base": "nominal (held)" if c.anchored else "refitted",
            "reference_fit": against[key], "parameters_fitted": st["k"], "bic": st["bic"],
            "kind": "noise model" if noise_model else "mechanism",
        }
        if rival_margin is not None:
            evidence["judged_on"] = (
                f"held-out one-step prediction (free-run gain not significant) and a BIC "
                f"margin of {rival_margin:.1f} over the noise model {c.cls.noise_rival}")
        try:
            model = cands.to_model(ctx, c, np.asarray(theta_fit[i - 1]), ints[i])
        except (TypeError, ValueError) as exc:
            # the fit ended where the effect's own constraints refuse its values (a clip
            # whose lower level passed its upper one): no valid model, so no finding
            st["decision"] = f"failed: the fitted values are not a valid {c.effect} ({exc})"
            continue
        text = model.describe(ctx, dict(
            y=y, v=v, n_fit=n_fit, ysim=ysim_all[i], ysim_ref=ysim_all[ref_i], u=u_all[i],
            ints=ints[i], tests=tests))
        evidence.update(text.pop("evidence", {}))
        findings.append((st["bic"], Finding(
            effect=c.effect, physics=text["physics"], where=_jsonable(text["where"]),
            parameters=_jsonable(text["parameters"]), model=model, metric=metric,
            fit_before=float(nom[key]), fit_after=float(st[key]), evidence=_jsonable(evidence)),
            i))
    findings.sort(key=lambda t: t[0])
    # one finding per effect: the variant (base refitted or held) the criterion prefers
    kept = {}
    for _, f, _ in findings:
        kept.setdefault(f.effect, f)
    if free_runs is not None:
        free_runs.update({id(f): ysim_all[i] for _, f, i in findings if kept[f.effect] is f})
    return list(kept.values())
