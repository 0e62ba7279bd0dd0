"""Why system 2 of the efficiency study (``identify_random.py --crlb --seed 11``) is biased:
the records hold its estimate to an inequality.

That system has ``nb = 1``, so its prediction ``y(t) = -a y(t-1) + b u(t-1)`` is linear in
``(a, b c1, b c2)`` once the play operator's sources are fixed: ``u(t)`` is a branch value
at an earlier input, ``P_k(v(tau))``, or the initial state. This script solves that linear
least-squares problem exactly with the *true* system's sources (the unconstrained
estimate), maps it to the paper's gauge, and checks whether the play operator run with the
estimate's own branches has those sources (the estimate is *feasible*). It compares both
with ``identify_giri`` then ``hbjax.refine`` (defaults) on the same records.

What it shows (``benchmarks/RESULTS.md``): ``P2``, fitted on the falling levels only, is
extrapolated to ``+h_m``, where the records show the output on ``P1`` (from rest, the play
reaches ``P1(h_m)`` only if ``P2(h_m) < P1(h_m)`` in the gauge's orientation). The
unconstrained estimate of ``P2(h_m)`` scatters far more widely than its distance from that
boundary, so in most realisations it crosses ``P1`` there and its sources are not the ones
it was solved with; the refinement (maximum likelihood under the play operator) stops
where ``P2`` no longer crosses. Where the unconstrained estimate is feasible, the
refinement reaches it exactly. The inequality is information the records hold: it biases
the estimate and takes its variance below the unconstrained Cramér–Rao bound.

Usage: ``python benchmarks/crlb_inequality.py [--draws 40] [--seed 11] [--system 2]``.
"""

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import hbjax

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from tests.generators.paper_class import (
    polyval_asc,
    predict_numpy,
    random_paper_system,
    to_hbjax,
)
from tests.generators.paper_runs import paper_records


def sources(c1, c2, v):
    """Per sample, ``(branch, time)`` whose value the play operator holds (``(None, None)``
    while it still holds the initial state 0)."""
    p1, p2 = polyval_asc(c1, v), polyval_asc(c2, v)
    lo, hi = np.minimum(p1, p2), np.maximum(p1, p2)
    state, now, out = 0.0, (None, None), []
    for t in range(len(v)):
        if state < lo[t]:
            state, now = lo[t], (0 if p1[t] <= p2[t] else 1, t)
        elif state > hi[t]:
            state, now = hi[t], (1 if p2[t] >= p1[t] else 0, t)
        out.append(now)
    return out


def unconstrained(sys_, records):
    """The least-squares estimate with the true sources, in the paper's gauge
    ``(a, b, c1, c2)``, and its sum of squared one-step errors."""
    m, h = sys_["m"], sys_["h_m"]
    rows, targets = [], []
    for v, y in records:
        src = sources(sys_["c1"], sys_["c2"], v)
        for t in range(1, len(v)):
            k, tau = src[t - 1]
            basis = np.zeros(2 * m)
            if k is not None:
                basis[k * m:(k + 1) * m] = v[tau] ** np.arange(m)
            rows.append(np.concatenate([[-y[t - 1]], basis]))
            targets.append(y[t])
    X, Y = np.array(rows), np.array(targets)
    beta = np.linalg.lstsq(X, Y, rcond=None)[0]
    bc1, bc2 = beta[1:1 + m], beta[1 + m:]
    b_mu = polyval_asc(bc2, -h) - polyval_asc(bc1, h)  # the gauge: P2(-h_m) - P1(h_m) = 1
    theta = np.concatenate([beta[:1], [b_mu], bc1 / b_mu, bc2 / b_mu])
    return theta, float(np.sum((Y - X @ beta) ** 2))


def ssr(theta, m, records):
    d = dict(a=theta[:1], b=theta[1:2], c1=theta[2:2 + m], c2=theta[2 + m:])
    return sum(float(np.sum((y[1:] - predict_numpy(d, v, y)[1:]) ** 2)) for v, y in records)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--system", type=int, default=2)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--T", type=int, default=3000)
    ap.add_argument("--level", type=float, default=0.01)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    for _ in range(args.system + 1):  # the study's sequence of systems
        sys_rng = np.random.default_rng(rng.integers(2**63))
        sys_ = random_paper_system(sys_rng)
    if sys_["nb"] != 1:
        raise SystemExit(f"system {args.system} has nb = {sys_['nb']}: the exact solve here "
                         "needs nb = 1 (linear in (a, b c1, b c2))")
    m, h = sys_["m"], sys_["h_m"]
    truth = hbjax.normalise(to_hbjax(sys_), h)
    theta0 = np.asarray(hbjax.flatten_params(truth))
    print(f"system {args.system} of seed {args.seed}: na = {sys_['na']}, nb = 1, m = {m}, "
          f"h_m = {h:.4g}; truth P1(h_m) = {float(truth.backlash.p1(h)):.4g}, "
          f"P2(h_m) = {float(truth.backlash.p2(h)):.4g}")
    refined, free_ls, feasible, p2h, gap = [], [], [], [], []
    bound = None
    for d in range(args.draws):
        design, records, sigma = paper_records(
            sys_, np.random.default_rng(sys_rng.integers(2**63)), args.level, args.T)
        theta_ls, ssr_ls = unconstrained(sys_, records)
        ok = abs(ssr(theta_ls, m, records) - ssr_ls) <= 1e-6 * ssr_ls
        giri = hbjax.identify_giri(design, *[y for _, y in records], throw=False)
        res = hbjax.refine(giri.model, records, h_m=h, throw=False)
        theta = np.asarray(hbjax.flatten_params(res.model))
        if bound is None:
            bound = np.diag(np.asarray(hbjax.crlb(truth, records, noise_std=sigma,
                                                  h_m=h).covariance))
        refined.append(theta)
        free_ls.append(theta_ls)
        feasible.append(ok)
        p2h.append(polyval_asc(theta_ls[2 + m:], h))
        gap.append(np.max(np.abs(theta - theta_ls) / np.sqrt(bound)))
        print(f"  draw {d}: {res.message[:20]}; unconstrained estimate feasible: {ok}; its "
              f"P2(h_m) {p2h[-1]:.3g}, refined {float(res.model.backlash.p2(h)):.3g}; "
              f"max |refined - unconstrained| / bound sd {gap[-1]:.3g}", flush=True)
    refined, free_ls, feasible, gap = map(np.array, (refined, free_ls, feasible, gap))
    names = hbjax.param_names(truth)
    keep = bound > 1e-12 * bound.max()
    print(f"\nunconstrained estimate feasible in {feasible.sum()} of {len(feasible)} draws; "
          f"where feasible, max |refined - unconstrained| / bound sd = "
          f"{gap[feasible].max() if feasible.any() else float('nan'):.3g}")
    print(f"unconstrained P2(h_m): mean {np.mean(p2h):.3g}, sd {np.std(p2h, ddof=1):.3g}")
    for label, est in (("refine (ML under the play operator)", refined),
                       ("unconstrained least squares", free_ls)):
        err = est - theta0
        print(f"{label}:")
        print("  parameter      " + " ".join(f"{n:>7}" for n, k in zip(names, keep) if k))
        for what, val in (("bias/sd", err.mean(0) / err.std(0, ddof=1)),
                          ("var/CRLB", err.var(0, ddof=1) / bound),
                          ("MSE/CRLB", np.mean(err**2, 0) / bound)):
            print(f"  {what:<14} " + " ".join(f"{x:7.2f}" for x, k in zip(val, keep) if k))


if __name__ == "__main__":
    main()
