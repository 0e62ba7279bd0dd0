"""Real recordings by the plain path: the Cascaded Tanks benchmark with the defaults of
``hbjax identify fit`` (orders (2, 2, 3), criterion "simulation", initial state estimated,
32 starts, seed 0), and the bundled friction-damper (BRFD) tests with ``hbjax.fit``, each
also with ``hbjax.fit``'s default criterion, "auto".

Prints the figures recorded in benchmarks/RESULTS.md ("Real data"). Run with
``nice python benchmarks/real_data.py`` (several minutes on 2 cores). ``--structures``
adds the structure sweep (validation RMSE per structure) and the estimation-only hold-out
rule: ``select_structure`` over m = 2..6 (na = nb = 2) fitted on the first 70% of the
estimation record and ranked by the free-run fit on its last 30%.
"""

import sys

import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import hbjax

PUBLISHED = {"best linear approximation": 0.75, "nonlinear state-space (PNLSS)": 0.34}


def poles(a):
    return float(np.max(np.abs(np.roots(np.concatenate([[1.0], np.asarray(a)])))))


def tanks(na=2, nb=2, m=3, criterion="simulation", starts=32):
    est, val = hbjax.datasets.cascaded_tanks()
    t0 = time.perf_counter()
    res = hbjax.fit((est.v, est.y), na=na, nb=nb, m=m, key=jax.random.key(0), starts=starts,
                    criterion=criterion, throw=False, progress=False)
    wall = time.perf_counter() - t0
    row = {"orders": (na, nb, m), "criterion": criterion, "result": res.message,
           "largest pole": poles(res.model.arx.a), "wall s": round(wall, 1)}
    for name, rec in (("estimation", est), ("validation", val)):
        for state in ("estimate", "zero"):
            row[f"{name} RMSE ({state})"] = hbjax.compare(res.model, rec.v, rec.y,
                                                          initial_state=state).rmse
    return row


def brfd(name, step=4, criterion="simulation"):
    rec = hbjax.datasets.brfd(name)
    v, y = rec.v[::step], rec.y[::step]
    try:
        res = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.key(0), starts=32,
                        criterion=criterion, progress=False)
    except hbjax.RefinementError as err:
        return {"record": name, "result": f"refused: {err}"[:160]}
    return {"record": name, "result": res.message, "criterion": res.criterion,
            "largest pole": poles(res.model.arx.a), "free-run fit %": float(res.sim_fit[0])}


def holdout_rule(fraction=0.7):
    est, _ = hbjax.datasets.cascaded_tanks()
    n = int(fraction * len(est.v))
    sel = hbjax.select_structure((est.v[:n], est.y[:n]), na=2, nb=2, m=[2, 3, 4, 5, 6],
                                 key=jax.random.key(0), criterion="simulation",
                                 validation=[(est.v[n:], est.y[n:])], rank_by="validation",
                                 progress=False)
    return sel.summary()


if __name__ == "__main__":
    if "--structures" in sys.argv:
        for orders in ((2, 2, 5), (2, 2, 6), (3, 3, 4), (3, 3, 5)):
            row = tanks(*orders)
            print(f"  {orders}: validation RMSE (estimate) {row['validation RMSE (estimate)']:.3f}"
                  f", estimation {row['estimation RMSE (estimate)']:.3f}", flush=True)
        print(holdout_rule(), flush=True)
    print("Cascaded Tanks, published validation RMSE:", PUBLISHED)
    for kw in ({}, {"criterion": "prediction"}, {"m": 4}, {"criterion": "auto"}):
        row = tanks(**kw)
        print("  " + "; ".join(f"{k}: {v:.3f}" if isinstance(v, float) else f"{k}: {v}"
                               for k, v in row.items()), flush=True)
    print("BRFD (decimated to 256 Hz), defaults of identify fit:")
    for name in hbjax.datasets.brfd_names():
        print("  ", brfd(name), flush=True)
    print("BRFD, hbjax.fit's default criterion (auto):")
    for name in hbjax.datasets.brfd_names():
        print("  ", brfd(name, criterion="auto"), flush=True)
