"""The closing-loop fits' shortfalls against the spread their own covariance predicts on
the estimation input and on the validation input.

For each run of ``identify_random.py --closing`` (same generator, seeds and draws: its
``run_fit``), the parameters are sampled from the estimate's covariance (400 draws) and
simulated on both inputs; printed: the category, the measured validation shortfall
(``100 - validation fit``), the result, ``loop_spread`` (first order, estimation input),
then the sampled shortfall's RMS, 90 % and 99 % quantiles on the estimation input
("est-mc") and on the validation input ("val-mc").

Usage::

    python benchmarks/closing_validation_spread.py 0,2,4 0/6/0,2/0/0,2/0/1,4/5/1

(seeds, then optional seed/system/draw triples to run alone.)
"""
import sys
from pathlib import Path
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import jax.numpy as jnp
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import identify_random as ir
import hbjax
from hbjax import flatten_params, unflatten_params
from tests.generators.paper_class import random_closing_loop_system

def mc(res, v, K=400):
    theta = np.asarray(flatten_params(res.model)); cov = np.asarray(res.covariance)
    if not np.all(np.isfinite(cov)): return (np.inf,)*3
    w, U = np.linalg.eigh(cov); L = U * np.sqrt(np.clip(w, 0, None))
    ths = theta + np.random.default_rng(1).normal(size=(K, theta.size)) @ L.T
    y0 = np.asarray(hbjax.simulate(res.model, v)); nrm = np.linalg.norm(y0 - y0.mean())
    sims = np.asarray(jax.vmap(lambda t: hbjax.simulate(unflatten_params(res.model, t), jnp.asarray(v)))(jnp.asarray(ths)))
    s = 100*np.linalg.norm(sims - y0, axis=1)/nrm
    s = s[np.isfinite(s)]
    return np.sqrt(np.mean(s**2)), np.quantile(s, 0.9), np.quantile(s, 0.99)

kept = {}
fit = hbjax.fit; simfit = ir.sim_fit
def keeping_fit(recordings, **kw):
    kept["r"], kept["v"] = fit(recordings, **kw), np.asarray(recordings[0][0]); return kept["r"]
def keeping_sim_fit(sys_, est, v):
    kept.setdefault("val", np.asarray(v)); return simfit(sys_, est, v)
ir.hbjax.fit = keeping_fit; ir.sim_fit = keeping_sim_fit
only = None if len(sys.argv) < 3 else {tuple(map(int, x.split("/"))) for x in sys.argv[2].split(",")}
for seed in map(int, sys.argv[1].split(",")):
    rng = np.random.default_rng(seed)
    for i in range(8):
        sys_rng = np.random.default_rng(rng.integers(2**63))
        system = random_closing_loop_system(sys_rng)
        for d in range(2):
            run_rng = np.random.default_rng(sys_rng.integers(2**63))
            if only and (seed, i, d) not in only: continue
            kept.clear()
            run = ir.run_fit(system, run_rng, 0.01, 6000, 32, 99.0, system["scale"], 10.0)
            r = kept.get("r")
            if r is None or "val" not in kept:
                print(seed, i, d, run["category"], flush=True); continue
            a = mc(r, kept["v"]); b = mc(r, kept["val"])
            print(seed, i, d, system["kind"], run.get("input"), run["category"],
                  f"{100-run.get('validation_fit', float('nan')):.2f}", r.message[:20],
                  f"lin={float(r.loop_spread):.3f}", "est-mc", " ".join(f"{x:.3f}" for x in a),
                  "val-mc", " ".join(f"{x:.3f}" for x in b), flush=True)
