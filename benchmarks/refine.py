"""Refinement benchmark: hbjax.refine vs scipy.optimize.least_squares on the same residual,
plus separable least squares and the closed form, on the paper's three experiments.

Run: ``.venv/bin/python benchmarks/refine.py`` (writes its section of RESULTS.md).

Problem: default system and design (n = 2, m = 3, h_m = 4), equation noise std 0.2,
T = 10 000 samples per experiment (30 000 residuals, 9 free parameters), prediction-error
criterion, paper normalisation, initial model = the closed-form estimate.
Peer: scipy's MINPACK Levenberg-Marquardt (``method="lm"``), finite-difference Jacobian,
residual computed by a Numba loop (play operator + ARX predictor), same elimination of
c2_0 as hbjax.
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
# The "compile" column measures compilation, not reads of the persistent cache.
os.environ.setdefault("HBJAX_NO_COMPILATION_CACHE", "1")

import jax  # noqa: E402
jax.config.update("jax_enable_x64", True)  # the estimators and the peers compare in float64
import jax.numpy as jnp  # noqa: E402
import numba  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

import hbjax  # noqa: E402
from hbjax._identify.giri import estimate_giri  # noqa: E402
from hbjax._identify.refine import refine_batch, refine_traceable  # noqa: E402
from hbjax._identify.criteria import lower_is_p1  # noqa: E402
from hbjax._identify.refine_band import labelled_from  # noqa: E402
from hbjax._identify.refine_solve import (  # noqa: E402
    gauge_transform, make_parametrisation, solve_criterion)
from hbjax._identify.separable import separable_traceable  # noqa: E402
import equinox as eqx  # noqa: E402
from _machine import describe, write_section  # noqa: E402

T, SIGMA, H_M = 10_000, 0.2, 4.0
SYSTEM, DESIGN = hbjax.default_system(), hbjax.default_design()
INPUTS = tuple(np.asarray(f(T)) for f in (DESIGN.constant_input, DESIGN.binary_input,
                                          DESIGN.staircase_input))


def records(key):
    return [np.asarray(hbjax.simulate(SYSTEM, v, SIGMA * jax.random.normal(k, (T,))))
            for v, k in zip(INPUTS, jax.random.split(key, 3))]


@numba.njit(cache=False)
def _residual_record(a, b, c1, c2, v, y, out):
    n, na, nb, m = v.shape[0], a.shape[0], b.shape[0], c1.shape[0]
    u = np.empty(n)
    state = 0.0
    for t in range(n):
        p1, p2 = c1[m - 1], c2[m - 1]
        for k in range(m - 2, -1, -1):
            p1 = p1 * v[t] + c1[k]
            p2 = p2 * v[t] + c2[k]
        state = min(max(state, min(p1, p2)), max(p1, p2))
        u[t] = state
    for t in range(n):
        acc = y[t]
        for i in range(na):
            if t - 1 - i >= 0:
                acc += a[i] * y[t - 1 - i]
        for i in range(nb):
            if t - 1 - i >= 0:
                acc -= b[i] * u[t - 1 - i]
        out[t] = acc


def theta_of(z):
    th = np.insert(z, 7, 0.0)
    k = np.arange(3)
    g = np.concatenate([np.zeros(4), -(H_M**k), (-H_M) ** k])
    th[7] = 1.0 - g @ th
    return th


def scipy_fit(z0, ys):
    out = np.empty(3 * T)

    def fun(z):
        th = theta_of(z)
        for j in range(3):
            _residual_record(th[:2], th[2:4], th[4:7], th[7:], INPUTS[j], ys[j],
                             out[j * T:(j + 1) * T])
        return out.copy()

    sol = least_squares(fun, z0, method="lm", xtol=1e-10, ftol=1e-10, gtol=1e-10)
    return theta_of(sol.x), sol.nfev


def cost(theta, ys):
    """Mean squared prediction error of a flattened model (the Numba residual)."""
    out = np.empty(3 * T)
    for j in range(3):
        _residual_record(theta[:2], theta[2:4], theta[4:7], theta[7:], INPUTS[j], ys[j],
                         out[j * T:(j + 1) * T])
    return float(np.mean(out**2))


def best_of(f, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        jax.block_until_ready(out)
        times.append(time.perf_counter() - t0)
    return min(times), out


def peer_comparison(fits=5):
    rows = []
    # What hbjax.refine runs (core_start=True: the core operator's solve from the start as
    # well, unless the labelled solve already ends on the core operator's model).
    refine_jit = jax.jit(lambda m, recs: refine_traceable(m, recs, h_m=H_M, core_start=True))
    full_jit = jax.jit(lambda m, recs: refine_traceable(m, recs, h_m=H_M, statistics=False,
                                                        core_start=True))
    sep_jit = jax.jit(lambda m, recs: separable_traceable(m, recs, h_m=H_M))
    compile_refine = compile_sep = None
    for i, key in enumerate(jax.random.split(jax.random.PRNGKey(100), fits)):
        ys = records(key)
        giri = hbjax.identify_giri(DESIGN, *ys)
        recs = tuple((jnp.asarray(v), jnp.asarray(y)) for v, y in zip(INPUTS, ys))
        if i == 0:
            t0 = time.perf_counter()
            jax.block_until_ready(refine_jit(giri.model, recs))
            compile_refine = time.perf_counter() - t0
            t0 = time.perf_counter()
            jax.block_until_ready(full_jit(giri.model, recs))
            compile_full = time.perf_counter() - t0
            t0 = time.perf_counter()
            jax.block_until_ready(sep_jit(giri.model, recs))
            compile_sep = time.perf_counter() - t0
        t_ours, res = best_of(lambda: refine_jit(giri.model, recs))
        t_full, full = best_of(lambda: full_jit(giri.model, recs))
        t_sep, sep = best_of(lambda: sep_jit(giri.model, recs))
        z0 = np.delete(np.asarray(hbjax.flatten_params(giri.model)), 7)
        _residual_record(*(np.zeros(2), np.zeros(2), np.zeros(3), np.zeros(3)), INPUTS[0],
                         ys[0], np.empty(T))  # compile the peer outside the timing
        t_peer, (peer, nfev) = best_of(lambda: scipy_fit(z0, ys))
        ours = np.asarray(hbjax.flatten_params(res.model))
        sep_p = np.asarray(hbjax.flatten_params(sep.model))
        scale = np.abs(peer).max()
        c_ours, c_peer = cost(ours, ys), cost(peer, ys)
        full_p = np.asarray(hbjax.flatten_params(full.model))
        rows.append(dict(t_ours=t_ours, t_full=t_full, full_steps=int(full.stats["steps"]),
                         full_diff=np.abs(full_p - ours).max() / scale, t_sep=t_sep, t_peer=t_peer, nfev=nfev,
                         c_ours=c_ours, c_peer=c_peer, code=int(res.result._value),
                         steps=int(res.stats["steps"]), sep_steps=int(sep.stats["steps"]),
                         diff=np.abs(ours - peer).max() / scale,
                         diff_std=np.max(np.abs(ours - peer) / np.asarray(res.std)),
                         sep_diff=np.abs(sep_p - ours).max() / scale))
        print(f"fit {i}: hbjax {t_ours * 1e3:.1f} ms ({rows[-1]['steps']} steps), full residual "
              f"{t_full * 1e3:.1f} ms, separable "
              f"{t_sep * 1e3:.1f} ms, scipy {t_peer * 1e3:.1f} ms ({nfev} evaluations), "
              f"max |hbjax - scipy| / max|theta| = {rows[-1]['diff']:.2e}, cost hbjax "
              f"{c_ours:.10g} scipy {c_peer:.10g}, hbjax code {rows[-1]['code']}")
    return rows, compile_refine, compile_full, compile_sep


def batching(count=20):
    """Per-fit time of refine_batch (lax.map) vs vmap over realisations."""
    keys = jax.random.split(jax.random.PRNGKey(7), count)
    ys = [records(k) for k in keys]
    models = [estimate_giri(DESIGN, *y).model for y in ys]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *models)
    inputs = tuple(jnp.asarray(v) for v in INPUTS)
    outputs = tuple(jnp.stack([jnp.asarray(y[k]) for y in ys]) for k in range(3))
    mapped = jax.jit(lambda m, o: refine_batch(m, inputs, o, h_m=H_M))
    vmapped = jax.jit(jax.vmap(lambda m, y1, y2, y3: refine_traceable(
        m, tuple(zip(inputs, (y1, y2, y3))), h_m=H_M)))
    jax.block_until_ready(mapped(stacked, outputs))
    jax.block_until_ready(vmapped(stacked, *outputs))
    t_map, _ = best_of(lambda: mapped(stacked, outputs), repeat=2)
    t_vmap, _ = best_of(lambda: vmapped(stacked, *outputs), repeat=2)
    return t_map / count, t_vmap / count


def accuracy(reps=200, chunk=50):
    """Monte Carlo: var / CRLB and bias of closed form, refined and separable estimates."""
    inputs = tuple(jnp.asarray(v) for v in INPUTS)

    @jax.jit
    def study(keys):
        def simulate(k):
            return tuple(SYSTEM.simulate_trajectory(v, SIGMA * jax.random.normal(kk, (T,)), 0.0)
                         for v, kk in zip(inputs, jax.random.split(k, 3)))

        ys = jax.vmap(simulate)(keys)
        giri = jax.vmap(lambda *y: estimate_giri(DESIGN, *y))(*ys)
        ref = refine_batch(giri.model, inputs, ys, h_m=H_M)
        sep = jax.lax.map(lambda a: separable_traceable(a[0], tuple(zip(inputs, a[1])),
                                                        h_m=H_M), (giri.model, ys))
        flat = jax.vmap(hbjax.flatten_params)
        return (flat(giri.model), flat(ref.model), ref.result._value, flat(sep.model),
                sep.result._value)

    keys = jax.random.split(jax.random.PRNGKey(42), reps)
    t0 = time.perf_counter()
    parts = [study(keys[i:i + chunk]) for i in range(0, reps, chunk)]
    jax.block_until_ready(parts)
    elapsed = time.perf_counter() - t0
    cat = [np.concatenate([p[j] for p in parts]) for j in range(5)]
    truth_model = hbjax.normalise(SYSTEM, H_M)
    truth = np.asarray(hbjax.flatten_params(truth_model))
    ys = records(jax.random.PRNGKey(3))
    bound = np.diag(np.asarray(hbjax.crlb(truth_model, list(zip(INPUTS, ys)), noise_std=SIGMA,
                                          h_m=H_M).covariance))
    out = {}
    for name, est, codes in (("closed form (identify_giri)", cat[0], np.zeros(reps, int)),
                             ("refined (hbjax.refine)", cat[1], cat[2]),
                             ("separable LS (hbjax.separable_ls)", cat[3], cat[4])):
        ok = codes == 0
        e = est[ok]
        out[name] = dict(ratio=e.var(0, ddof=1) / bound,
                         bias=(e.mean(0) - truth) / e.std(0, ddof=1), failed=int((~ok).sum()))
    return out, elapsed, reps


def breakdown():
    """Per-fit time of refine's stages on the first realisation: the Levenberg-Marquardt
    solve alone, with the band checks (touch equalities, labelled vs core operator), and
    the whole refinement (plus the result's checks: free-run fit, stability, identifiability)."""
    ys = records(jax.random.split(jax.random.PRNGKey(100), 5)[0])
    model = hbjax.identify_giri(DESIGN, *ys).model
    recs = tuple((jnp.asarray(v), jnp.asarray(y)) for v, y in zip(INPUTS, ys))
    options = dict(max_steps=256, rtol=1e-7, atol=1e-7)

    def start(m, recs):
        par = make_parametrisation(m, recs, H_M)
        gauged, _ = gauge_transform(m, par)
        par = eqx.tree_at(lambda p: p.lower_is_p1, par, lower_is_p1(gauged, recs))
        return par, par.free(hbjax.flatten_params(gauged))

    stages = {
        "solve": lambda m, r: solve_criterion(*start(m, r), r, "prediction", True, options),
        "solve + band checks": lambda m, r: labelled_from(*start(m, r), r, "prediction",
                                                          True, options),
        "refine": lambda m, r: refine_traceable(m, r, h_m=H_M, core_start=True),
    }
    out = {}
    for name, f in stages.items():
        g = jax.jit(f)
        jax.block_until_ready(g(model, recs))
        out[name] = best_of(lambda: g(model, recs), repeat=7)[0]
    return out


def main():
    print(describe())
    load_start = os.getloadavg()[0]
    rows, c_ref, c_full, c_sep = peer_comparison()
    t_ours = np.median([r["t_ours"] for r in rows])
    t_full = np.median([r["t_full"] for r in rows])
    ratios = [r["t_peer"] / r["t_ours"] for r in rows]
    t_sep = np.median([r["t_sep"] for r in rows])
    t_peer = np.median([r["t_peer"] for r in rows])
    same = [r for r in rows if abs(r["c_ours"] - r["c_peer"]) <= 1e-9 * r["c_peer"]]
    worst = max((r["diff"] for r in same), default=float("nan"))
    worst_std = max((r["diff_std"] for r in same), default=float("nan"))
    other = [r for r in rows if r not in same]
    other_txt = "".join(
        f" In {len(other)} of {len(rows)} fits scipy stopped elsewhere: "
        + "; ".join(f"cost scipy {r['c_peer']:.8g} vs hbjax {r['c_ours']:.8g} "
                    f"(max rel. difference {r['diff']:.1e})" for r in other)
        + ". Its sorted band (L = min, H = max) lets the closed-form start's crossed branches "
          "fit an outer staircase level with the wrong branch, a spurious local minimum "
          "that hbjax's labelled band avoids (docs/refinement.md)." if other else "")
    worst_sep = max(r["sep_diff"] for r in rows)
    stages = breakdown()
    t_map, t_vmap = batching()
    acc, elapsed, reps = accuracy()
    names = hbjax.param_names(SYSTEM)
    lines = [
        f"Machine: {describe()}. Paper's three experiments (default system, n=2, m=3, "
        f"h_m=4), T = {T} samples each (30 000 residuals, 9 free parameters), equation noise "
        f"std {SIGMA}, prediction-error criterion, paper normalisation, start = closed form. "
        "Best of 3 runs per fit, median over 5 noise realisations. 1-minute load average "
        f"{load_start:.1f} at the start of this run and {os.getloadavg()[0]:.1f} at the end "
        f"(on {os.cpu_count()} cores): timings taken under load are noisy.",
        "",
        "| implementation | compile (s) | time per fit (ms) | vs scipy | steps / evaluations |",
        "|---|---|---|---|---|",
        f"| hbjax.refine (optimistix LM on the Gram matrix, a data pass per round; the core "
        f"start's solve skipped where the labelled optimum is already the core model) | {c_ref:.1f} "
        f"| {t_ours * 1e3:.1f} | {t_peer / t_ours:.2f}x | "
        f"{np.median([r['steps'] for r in rows]):.0f} steps |",
        f"| refine_traceable(statistics=False) (optimistix LM on the full residual, closed-form "
        f"Jacobian, a data pass per step) | {c_full:.1f} | {t_full * 1e3:.1f} | "
        f"{t_peer / t_full:.2f}x | {np.median([r['full_steps'] for r in rows]):.0f} steps |",
        f"| hbjax.separable_ls (variable projection, Bai 2002) | {c_sep:.1f} | {t_sep * 1e3:.1f} "
        f"| {t_peer / t_sep:.2f}x | {np.median([r['sep_steps'] for r in rows]):.0f} steps |",
        f"| scipy.optimize.least_squares(method='lm'), Numba residual, FD Jacobian | "
        f"numba JIT | {t_peer * 1e3:.1f} | 1x | {np.median([r['nfev'] for r in rows]):.0f} "
        "residual evaluations |",
        "",
        f"Target: hbjax >= 3x faster per fit after compilation; measured "
        f"{t_peer / t_ours:.2f}x ({'met' if t_peer >= 3 * t_ours else 'MISSED'}; fit by fit "
        f"{min(ratios):.1f}x to {max(ratios):.1f}x, each side timed best of 3 right after the "
        "other). Agreement with scipy where both reach the same cost "
        f"({len(same)} of {len(rows)} fits): max |theta_hbjax - theta_scipy| / max |theta| = "
        f"{worst:.1e} (target 1e-6), i.e. {worst_std:.1e} standard errors.{other_txt} "
        f"Full-residual path vs Gram path: "
        f"{max(r['full_diff'] for r in rows):.1e}. Separable LS vs refine: {worst_sep:.1e}.",
        "",
        "Where a fit's time goes (first realisation, best of 7): the Levenberg-Marquardt "
        f"solve {stages['solve'] * 1e3:.1f} ms; with the band checks (touch equalities, "
        f"labelled vs core operator) {stages['solve + band checks'] * 1e3:.1f} ms; the whole "
        f"refinement {stages['refine'] * 1e3:.1f} ms, the rest being the result's checks "
        "(free-run simulation fit on every record, stability, identifiability).",
        "",
        f"Batches of 20 realisations (`refine_batch`): {t_map * 1e3:.0f} ms per fit with the "
        f"default sequential `lax.map` ({t_peer / t_map:.2f}x scipy's single fit), "
        f"{t_vmap * 1e3:.0f} ms per fit with `jax.vmap` (a vmapped fit runs every lane for "
        "the slowest one, and the fallback's `lax.cond` becomes a select that runs both "
        "paths).",
        "",
        f"Accuracy, Monte Carlo with {reps} realisations ({elapsed:.0f} s for all three "
        "estimators incl. compilation): var / CRLB and bias / std per normalised parameter "
        "(CRLB from `hbjax.crlb`, constrained; realisations whose refined branches cross at "
        "a recorded input are counted as failed and excluded).",
        "",
        "| estimator | failed | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for name, a in acc.items():
        lines.append(f"| {name}: var/CRLB | {a['failed']} | "
                     + " | ".join(f"{x:.2f}" for x in a["ratio"]) + " |")
        lines.append(f"| {name}: bias/std | | "
                     + " | ".join(f"{x:+.3f}" for x in a["bias"]) + " |")
    lines += [
        "",
        "The slow test `tests/test_refine.py::test_refined_estimator_reaches_the_cramer_rao_bound` "
        "checks var/CRLB <= 1.2 and |bias| <= 0.1 std on 500 realisations.",
    ]
    body = "\n".join(lines)
    print(body)
    write_section("Refinement", body)


if __name__ == "__main__":
    main()
