"""Does refinement depend on the unit of the output?

The same records with the output multiplied by a unit (1e-12 .. 1e8), the start's backlash
by the same unit: `refine` (both criteria) and `separable_ls` should give the same free-run
fit, the same step count up to rounding, and standard errors carried by the unit.

1. The default system, 400 samples of random levels, noise std 0.1, a start 20 % off the
   truth: one table row per unit.
2. Random paper-class systems of the independent generator (``tests/generators``), random
   inputs, noise 2 % of the output's spread, a start 10 % off, a log-uniform unit in
   1e-9..1e9: how often the unit changes the result code, the fit (by more than 1e-4 %) or a
   finite standard error (by more than 1e-3 relative).

Run: ``python benchmarks/output_unit.py [--systems N]`` (about 2 minutes for 20 systems).
"""

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import hbjax  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from tests.generators.paper_class import INPUT_KINDS  # noqa: E402
from tests.generators.paper_runs import (  # noqa: E402
    ordinary_record_and_start, output_unit_weights,
)


def scaled(model, unit):
    bl = model.backlash
    return hbjax.Hammerstein(hbjax.Backlash(np.asarray(bl.c1) * unit, np.asarray(bl.c2) * unit),
                             model.arx)


def default_table():
    model = hbjax.default_system()
    rng = np.random.default_rng(0)
    levels = rng.uniform(-6, 6, 40)
    v = np.repeat(levels, 10)
    y = np.asarray(hbjax.simulate(model, v, 0.1 * rng.standard_normal(v.size)))
    start = hbjax.Hammerstein(
        hbjax.Backlash(np.asarray(model.backlash.c1) * 1.2, np.asarray(model.backlash.c2) * 0.8),
        hbjax.ARX(np.asarray(model.arx.a) * 0.9, np.asarray(model.arx.b) * 1.2))
    print("| output unit | prediction: fit % / steps / std(a1) / result | simulation: fit % / "
          "steps / result | separable LS: fit % / std(a1) |")
    print("|---|---|---|---|")
    for unit in (1.0, 1e-6, 1e6, 1e-12, 1e8):
        p = hbjax.refine(scaled(start, unit), (v, y * unit), throw=False)
        s = hbjax.refine(scaled(start, unit), (v, y * unit), criterion="simulation",
                         throw=False)
        sep = hbjax.separable_ls(scaled(start, unit), (v, y * unit), throw=False)
        print(f"| {unit:g} | {float(p.sim_fit_pooled):.2f} / {int(p.stats['steps'])} / "
              f"{float(p.std[0]):.3g} / {p.message[:40]} | {float(s.sim_fit_pooled):.2f} / "
              f"{int(s.stats['steps'])} / {s.message[:40]} | {float(sep.sim_fit_pooled):.2f} / "
              f"{float(sep.std[0]):.3g} |")


def random_systems(count):
    differ = {"result": 0, "fit": 0, "std": 0}
    worst_fit = 0.0
    for seed in range(count):
        rng = np.random.default_rng(1000 + seed)
        sys_, v, y, start = ordinary_record_and_start(
            rng, T=800, kind=INPUT_KINDS[seed % len(INPUT_KINDS)], m=int(rng.integers(2, 5)))
        unit = float(10.0 ** rng.uniform(-9, 9))
        h_m = sys_["h_m"] if seed % 2 else None
        base = hbjax.refine(start, (v, y), h_m=h_m, throw=False)
        other = hbjax.refine(scaled(start, unit), (v, y * unit), h_m=h_m, throw=False)
        differ["result"] += str(base.result) != str(other.result)
        gap = abs(float(base.sim_fit_pooled) - float(other.sim_fit_pooled))
        worst_fit = max(worst_fit, gap)
        differ["fit"] += gap > 1e-4
        # (a coefficient the gauge fixes, b_1 with nb = 1, has std 0 in every unit)
        ok = np.isfinite(np.asarray(base.std)) & (np.asarray(base.std) > 0)
        rel = np.abs(np.asarray(other.std)[ok] / output_unit_weights(base, unit)[ok]
                     / np.asarray(base.std)[ok] - 1)
        if np.any(rel > 1e-3):
            differ["std"] += 1
            print(f"system {seed} (na {sys_['na']}, m {sys_['m']}, unit {unit:.3g}): std "
                  f"ratios {np.round(1 + rel, 4)}; unidentified {base.unidentified} / "
                  f"{other.unidentified}")
    print(f"\n{count} random paper-class systems (units log-uniform in 1e-9..1e9, gauges "
          f"alternating): result code differs {differ['result']}, fit differs by > 1e-4 % "
          f"{differ['fit']} (largest gap {worst_fit:.2g} %), a finite std differs by > 1e-3 "
          f"{differ['std']}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", type=int, default=20)
    args = parser.parse_args()
    default_table()
    random_systems(args.systems)


if __name__ == "__main__":
    main()
