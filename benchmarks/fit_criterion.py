"""``hbjax.fit``'s default criterion ``"auto"`` against the prediction criterion, with the
noise in the equation and at the output, on the independent generator
(``tests/generators/paper_class.py``): random paper-class systems (orders 1-3, m = 3), one
estimation record of each input kind (T samples, from rest), noise std ``level`` x the
noise-free output's range (equation noise scaled by the root sum of squares of ``1/A``'s
impulse response, so that its part of the output has that std too); validation free-run fit
(`hbjax.compare`, estimated initial state) on a fresh noise-free record of the same kind.

Run from the repository root:
``python benchmarks/fit_criterion.py --systems 10 --levels 0.01,0.03,0.1 --seed 0``;
heavier sensor noise on shorter records, where the prediction criterion can find no success
and ``"auto"`` searches again with the output-error criterion:
``python benchmarks/fit_criterion.py --systems 10 --levels 0.1,0.2 --T 800 --seed 1``.
"""
import argparse
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, "tests")

import numpy as np
from generators.paper_class import INPUT_KINDS, random_input, random_paper_system, simulate_numpy
from generators.paper_runs import noise_gain

import hbjax


def validation_fit(model, v, y):
    return float(np.atleast_1d(hbjax.compare(model, v, y).fit)[0])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--systems", type=int, default=10)
    ap.add_argument("--levels", default="0.01,0.03,0.1")
    ap.add_argument("--T", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    levels = [float(x) for x in args.levels.split(",")]
    rng = np.random.default_rng(args.seed)
    rows = []
    print("system kind na nb where level | auto: criterion ok val | prediction: ok val | "
          "simulation: ok val | t_auto t_pred t_sim")
    for k in range(args.systems):
        s = random_paper_system(rng, n=int(rng.integers(1, 4)), m=3)
        kind = INPUT_KINDS[k % len(INPUT_KINDS)]
        v = random_input(rng, kind, args.T, 1.5 * s["h_m"])
        y_clean = simulate_numpy(s, v)[0]
        v_val = random_input(rng, kind, 2000, 1.5 * s["h_m"])
        y_val = simulate_numpy(s, v_val)[0]
        for level in levels:
            for where in ("equation", "output"):
                noise = rng.standard_normal(args.T) * level * np.ptp(y_clean)
                y = (y_clean + noise if where == "output"
                     else simulate_numpy(s, v, noise / noise_gain(s["a"]))[0])
                fits = {}
                for crit in ("auto", "prediction", "simulation"):
                    t = time.perf_counter()
                    r = hbjax.fit((v, y), na=s["na"], nb=s["nb"], m=3, key=jax.random.key(k),
                                  criterion=crit, throw=False, progress=False)
                    ok = bool(r.result == hbjax.RESULTS.successful)
                    fits[crit] = (r, ok, validation_fit(r.model, v_val, y_val) if ok else np.nan,
                                  time.perf_counter() - t)
                (ra, oka, va, ta), (_, okp, vp, tp) = fits["auto"], fits["prediction"]
                _, oks, vs, ts = fits["simulation"]
                rows.append((where, level, ra.criterion, oka, va, okp, vp, oks, vs))
                print(f"{k} {kind} {s['na']} {s['nb']} {where} {level:g} | {ra.criterion} "
                      f"{oka} {va:.2f} | {okp} {vp:.2f} | {oks} {vs:.2f} | {ta:.1f} {tp:.1f} "
                      f"{ts:.1f}", flush=True)
    print("\nwhere level | runs | auto chose simulation | success auto / prediction | "
          "median val auto / prediction / simulation | lowest val auto / prediction / simulation "
          "| auto below prediction by > 1 | auto below simulation by > 1 "
          "| auto's successes where prediction failed: count, their validation fits")
    for where in ("equation", "output"):
        for level in levels:
            sel = [r for r in rows if r[0] == where and r[1] == level]
            sim = sum(r[2] == "simulation" for r in sel)
            va = np.array([r[4] for r in sel]); vp = np.array([r[6] for r in sel])
            vs = np.array([r[8] for r in sel])
            worse = int(np.sum(va < vp - 1.0))
            worse_sim = int(np.sum(va < vs - 1.0))
            rescued = [r[4] for r in sel if r[3] and not r[5]]
            print(f"{where} {level:g} | {len(sel)} | {sim} | {sum(r[3] for r in sel)} / "
                  f"{sum(r[5] for r in sel)} | {np.nanmedian(va):.2f} / {np.nanmedian(vp):.2f} / "
                  f"{np.nanmedian(vs):.2f} | {np.nanmin(va):.2f} / {np.nanmin(vp):.2f} / "
                  f"{np.nanmin(vs):.2f} | {worse} | {worse_sim} | "
                  f"{len(rescued)}, {', '.join(f'{x:.1f}' for x in sorted(rescued))}")


if __name__ == "__main__":
    main()
