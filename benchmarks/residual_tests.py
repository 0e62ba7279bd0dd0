"""What the residual tests inside every result change (``docs/validation.md``, "What fit
and refine may call a success"), counted on the families of ``tests/test_adequacy.py``
over more seeds:

- slow random systems whose true model simulates below the 0 % floor, refined from the
  truth (prediction criterion): successes, those accepted only by the residual tests
  (``noise_limited``), refusals by code;
- outputs unrelated to the input (random walks, slow AR(1) noise), refined from a slow
  random system with each criterion: successes now, and "before" (``no_input_effect``
  results whose free-run fit clears the floor: what the earlier code called a success);
  controls (the systems' own outputs, integrated noise 10 % of the input-driven std).

Usage: ``python benchmarks/residual_tests.py`` (about 5 minutes on 2 cores).
"""

import collections
import os
import sys

import jax
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
jax.config.update("jax_enable_x64", True)

import hbjax
from tests.generators.paper_class import (
    INPUT_KINDS,
    random_input,
    simulate_numpy,
    to_hbjax,
)
from tests.test_adequacy import N, _free_run_fit, _slow_system


def _integrated_noise_scale(sys, v, det):
    """Equation-noise std per unit of integrated noise std over the input-driven std."""
    h = simulate_numpy(dict(sys, b=np.zeros(sys["nb"])), v, np.eye(1, N)[0])[0]
    return np.std(det) / np.sqrt(np.sum(h**2))


def slow_systems(seeds=(1000, 1001), per_seed=30):
    counts = collections.Counter()
    for seed in seeds:
        rng = np.random.default_rng(seed)
        cases = 0
        while cases < per_seed:
            sys = _slow_system(rng)
            v = random_input(rng, INPUT_KINDS[int(rng.integers(len(INPUT_KINDS)))], N, 2 * sys["h_m"])
            det, _ = simulate_numpy(sys, v)
            sigma = rng.uniform(1.2, 2.0) * _integrated_noise_scale(sys, v, det)
            y, _ = simulate_numpy(sys, v, sigma * rng.normal(size=N))
            if not _free_run_fit(y, det) < 0:
                continue
            cases += 1
            res = hbjax.refine(to_hbjax(sys), [(v, y)], throw=False)
            ok = res.message.startswith("success")
            counts["truths below the floor"] += 1
            counts["success"] += ok
            counts["accepted by the residual tests"] += ok and bool(res.noise_limited)
            if not ok:
                counts[f"refused: {res.message[:60]}"] += 1
    return counts


def unrelated_outputs(criterion, seeds=(2000, 2001, 2002), draws=8):
    counts = collections.Counter()
    for seed in seeds:
        rng = np.random.default_rng(seed)
        for d in range(draws):
            sys = _slow_system(rng)
            v = random_input(rng, INPUT_KINDS[int(rng.integers(len(INPUT_KINDS)))], N, 2 * sys["h_m"])
            det, _ = simulate_numpy(sys, v)
            if d % 2:
                y = np.cumsum(rng.normal(size=N))
            else:
                y = simulate_numpy(dict(sys, b=np.zeros(sys["nb"]), a=[-rng.uniform(0.99, 0.999)]),
                                   v, rng.normal(size=N))[0]
            y = y * np.std(det) / np.std(y)
            res = hbjax.refine(to_hbjax(sys), [(v, y)], criterion=criterion, throw=False)
            success = res.message.startswith("success")
            counts["records"] += 1
            counts["success"] += success
            counts["success before the tests"] += success or bool(
                res.result == hbjax.RESULTS.no_input_effect and float(res.sim_fit_pooled) >= 0)
            if d % 4 == 0:
                noise = 0.1 * _integrated_noise_scale(sys, v, det) * rng.normal(size=N)
                own = hbjax.refine(to_hbjax(sys), [(v, simulate_numpy(sys, v, noise)[0])],
                                   criterion=criterion, throw=False)
                counts["controls"] += 1
                counts["controls success"] += own.message.startswith("success")
    return counts


if __name__ == "__main__":
    print("slow systems, truth below the floor:", dict(slow_systems()), flush=True)
    for criterion in ("prediction", "simulation"):
        print(f"unrelated outputs, {criterion} criterion:", dict(unrelated_outputs(criterion)), flush=True)
