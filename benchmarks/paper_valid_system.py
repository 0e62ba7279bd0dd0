"""The paper's three experiments on one valid system whose branches are about 1.3 apart
everywhere on [-2 h_m, 2 h_m] (n = 2, m = 3, h_m = 3, T = 6000 per experiment):
``identify_giri`` then ``refine(..., h_m)`` with the defaults, over noise draws at two
levels, each compared with the refinement started from the true system on the same records.

    python benchmarks/paper_valid_system.py [--draws 40]

Prints one line per run and a count of outcomes per noise level. A run counts as a failure
if either step reports a failure, or the refined cost is more than 20 sigma^2 above the
cost of the refinement from the truth (a local minimum)."""

import argparse
import collections

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import hbjax

H_M = 3.0
T = 6000


def system():
    c1 = np.array([-0.65, 0.5, 0.02])
    return hbjax.Hammerstein(hbjax.Backlash(c1, c1 + np.array([1.3, 0.0, 0.0])),
                             hbjax.ARX(np.array([-1.2, 0.35]), np.array([0.5, 0.3])))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40, help="noise draws per level")
    args = ap.parse_args(argv)
    truth = system()
    design = hbjax.GiriDesign(2, 3, H_M)
    inputs = [design.constant_input(T), design.binary_input(T), design.staircase_input(T)]
    outcomes = collections.Counter()
    for std in (0.05, 0.2):
        for k in range(args.draws):
            rng = np.random.default_rng(1000 * k + int(std * 100))
            ys = [np.asarray(hbjax.simulate(truth, v, std * rng.standard_normal(T))) for v in inputs]
            giri = hbjax.identify_giri(design, *ys, throw=False)
            if giri.result != hbjax.RESULTS.successful:
                outcomes[(std, "closed form: " + giri.message[:60])] += 1
                continue
            records = list(zip(inputs, ys))
            ref = hbjax.refine(giri.model, records, h_m=H_M, throw=False)
            from_truth = hbjax.refine(hbjax.normalise(truth, H_M), records, h_m=H_M, throw=False)
            excess = (float(ref.stats["cost"]) - float(from_truth.stats["cost"])) \
                * float(ref.stats["samples"]) / std**2
            verdict = ref.message[:60] if ref.message != "success" else (
                "local minimum" if excess > 20 else "success")
            outcomes[(std, verdict)] += 1
            print(f"noise {std} draw {k}: {verdict} (cost above the truth's refinement "
                  f"{excess:.3g} sigma^2)", flush=True)
    for (std, verdict), count in sorted(outcomes.items()):
        print(f"noise std {std}: {verdict}: {count} of {args.draws}")


if __name__ == "__main__":
    main()
