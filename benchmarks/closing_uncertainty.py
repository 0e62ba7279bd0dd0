"""How far the closing-loop fits are from the 99 % validation target, against how far
their own covariance says they can be.

The runs are exactly those of ``identify_random.py --closing`` (same generator, seeds and
random draws: this script calls its ``run_fit``, wrapping ``hbjax.fit`` only to keep each
run's result). For every run it prints:

- the measured shortfall, ``100 - validation fit`` (noise-free free run of the estimate
  against the truth's on a fresh input of the record's kind, as ``identify_random.py``);
- the *predicted* shortfall from the estimate's own covariance ``Sigma`` (the
  Gauss-Newton covariance every ``FitResult`` carries), propagated to the free run on the
  estimation input by ``FitResult.free_run_std``:
  ``100 sqrt(trace(J Sigma J^T)) / ||y_sim - mean(y_sim)||`` with ``J = d y_sim / d theta``.

Where the two agree, a run below 99 % is not a bad model but the statistical resolution of
the record: no estimator that uses these data can promise the target.

Usage::

    python benchmarks/closing_uncertainty.py --seed 0 --systems 8 --draws 2
"""

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import identify_random as ir

import hbjax
from tests.generators.paper_class import random_closing_loop_system


def predicted_shortfall(result, v) -> float:
    """``100 sqrt(sum_t std_t^2) / ||y_sim - mean||`` on the input ``v`` (percent), with
    ``std_t`` the result's own :meth:`free_run_std` (``inf`` if an unidentified parameter
    moves the output)."""
    y_sim = np.asarray(hbjax.simulate(result.model, v))
    std = np.asarray(result.free_run_std(v))
    return float(100.0 * np.sqrt(np.sum(std**2)) / np.linalg.norm(y_sim - y_sim.mean()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--systems", type=int, default=8)
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--T", type=int, default=6000)
    ap.add_argument("--starts", type=int, default=32)
    args = ap.parse_args(argv)

    kept = {}
    fit = hbjax.fit

    def keeping_fit(recordings, **kwargs):
        kept["result"], kept["v"] = fit(recordings, **kwargs), np.asarray(recordings[0][0])
        return kept["result"]

    ir.hbjax.fit = keeping_fit  # identify_random's own `hbjax` module object
    rng = np.random.default_rng(args.seed)
    rows = []
    print("system draw kind na m input category measured-shortfall predicted-shortfall")
    for i in range(args.systems):
        sys_rng = np.random.default_rng(rng.integers(2**63))
        system = random_closing_loop_system(sys_rng)
        for d in range(args.draws):
            run_rng = np.random.default_rng(sys_rng.integers(2**63))
            kept.clear()
            run = ir.run_fit(system, run_rng, 0.01, args.T, args.starts, 99.0, system["scale"], 10.0)
            if "validation_fit" not in run:
                print(i, d, system["kind"], system["na"], system["m"], run.get("input"), run["category"],
                      "-", "-", flush=True)
                continue
            measured = 100.0 - run["validation_fit"]
            predicted = predicted_shortfall(kept["result"], kept["v"])
            rows.append((measured, predicted, run["category"]))
            print(i, d, system["kind"], system["na"], system["m"], run["input"], run["category"],
                  f"{measured:.2f}", f"{predicted:.2f}", flush=True)
    ir.hbjax.fit = fit
    if rows:
        m, p, cat = (np.array([r[k] for r in rows]) for k in range(3))
        miss = cat != "ok"
        print(f"runs {len(rows)}, below 99 %: {int(np.sum(m > 1.0))}; "
              f"correlation(log measured, log predicted) {np.corrcoef(np.log(m), np.log(p))[0, 1]:.2f}; "
              f"median measured/predicted {np.median(m / p):.2f}; "
              f"runs below 99 % with predicted shortfall >= 1 %: {int(np.sum((m > 1.0) & (p >= 1.0)))}, "
              f"with predicted < 1 %: {int(np.sum((m > 1.0) & (p < 1.0)))}; "
              f"runs at or above 99 % with predicted >= 1 %: {int(np.sum((m <= 1.0) & (p >= 1.0)))}; "
              f"not ok: {int(miss.sum())}")


if __name__ == "__main__":
    main()
