"""The defaults of ``hbjax identify fit`` (criterion simulation, initial state estimated,
stable search) against the prediction criterion on the independent generator
(tests/generators/paper_class.py): 3 random paper-class systems (n = 2, m = 3), 1500-sample
estimation records cut from the middle of a run (not at rest), output noise 1% of the
output range; validation free-run fit (estimated initial state) of the fitted model and of
the true system. Run from the repository root: ``nice python benchmarks/fit_defaults.py``.
"""
import sys

import jax

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, "tests")

import numpy as np
from generators.paper_class import random_input, random_paper_system, to_hbjax

import hbjax

for seed in range(3):
    rng = np.random.default_rng(100 + seed)
    s = random_paper_system(rng, n=2, m=3)
    true = to_hbjax(s)
    N, skip = 1500, 300
    v = random_input(rng, "plateaus_sines", 2 * (N + skip), 2 * s["h_m"])
    y = np.asarray(hbjax.simulate(true, v))
    sig = 0.01 * s["out_range"]
    ve, ye = v[skip:N + skip], y[skip:N + skip] + sig * rng.normal(size=N)
    vv, yv = v[N + 2 * skip:], y[N + 2 * skip:] + sig * rng.normal(size=v.size - N - 2 * skip)
    for crit in ("simulation", "prediction"):
        r = hbjax.fit((ve, ye), na=2, nb=2, m=3, key=jax.random.key(0), starts=16, criterion=crit, throw=False, progress=False)
        c = hbjax.compare([r.model, true], vv, yv)
        print(seed, crit, r.message[:20], f"val fit model {c.fits[0]:.2f} truth {c.fits[1]:.2f}", flush=True)
