"""Structure selection on random paper-class systems: how often does BIC pick the true
``(na, nb, m)``? Systems from ``tests/generators/paper_class.py`` (independent of the
package), random-level inputs, noise a fraction of the output range.

Run: ``.venv/bin/python benchmarks/select_structure.py [--systems 10 --n 2 --m 3]``.
"""

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import hbjax

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from _machine import describe, write_section
from generators import paper_class as pc


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--systems", type=int, default=10)
    parser.add_argument("--n", type=int, default=2)
    parser.add_argument("--m", type=int, default=3)
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--noise", type=float, default=0.01, help="fraction of the output range")
    parser.add_argument("--starts", type=int, default=16)
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args()
    n, m, N = args.n, args.m, args.samples
    na_grid, m_grid = range(max(n - 1, 1), n + 2), range(max(m - 1, 2), m + 2)
    truth = (n, n, m)
    rows, start = [], time.perf_counter()
    for seed in range(args.systems):
        rng = np.random.default_rng(1000 + seed)
        s = pc.random_paper_system(rng, n=n, m=m)
        v = pc.random_input(rng, "prbs_levels", N, 2 * s["h_m"])
        clean, _ = pc.simulate_numpy(s, v)
        sd = args.noise * np.ptp(clean)
        y, _ = pc.simulate_numpy(s, v, sd * rng.normal(size=N))
        v_val = pc.random_input(rng, "prbs_levels", N, 2 * s["h_m"])
        y_val, _ = pc.simulate_numpy(s, v_val, sd * rng.normal(size=N))
        sel = hbjax.select_structure((v, y), na=na_grid, nb=n, m=m_grid,
                                     key=jax.random.PRNGKey(seed), starts=args.starts,
                                     validation=(v_val, y_val), progress=False)
        by_val = sel.orders[int(np.nanargmax(np.where(sel.success, sel.validation_fit, -np.inf)))]
        rows.append((seed, s["delay"], s["gap_rel"], sel.best, by_val,
                     float(sel.validation_fit[0])))
        print(f"system {seed}: BIC picks {sel.best}, validation fit picks {by_val}", flush=True)
    hits = sum(r[3] == truth for r in rows)
    hits_val = sum(r[4] == truth for r in rows)
    lines = [
        f"Machine: {describe()}; load average {os.getloadavg()[0]:.1f} at the end.",
        (f"{args.systems} random paper-class systems, na = nb = {n}, m = {m}, N = {N} random-level "
        f"samples, noise {100 * args.noise:g}% of the output range, {args.starts} starts; grid "
        f"na in {list(na_grid)}, nb = {n}, m in {list(m_grid)}; "
        f"{time.perf_counter() - start:.0f} s in all (compilation included)."),
        "",
        "| system | delay | band / range | BIC picks | validation fit picks | val. fit of BIC pick (%) |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {s} | {d} | {g:.3f} | {b} | {bv} | {f:.2f} |" for s, d, g, b, bv, f in rows]
    lines += ["", (f"True structure {truth} picked by BIC in {hits}/{len(rows)} systems, "
                  f"by the highest validation fit in {hits_val}/{len(rows)}.")]
    report = "\n".join(lines)
    print(report)
    if not args.no_write:
        write_section("Structure selection (benchmarks/select_structure.py)", report)


if __name__ == "__main__":
    main()
