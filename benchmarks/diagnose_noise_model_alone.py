"""`hbjax.diagnose` with only the coloured-noise effect offered (beside the base candidates),
on recordings of the default system with an added input-driven term the library has no
mechanism for (a slow first-order response to v|v|, 3|v| or v^3/6) and, as a control, with
AR(1)-coloured noise alone. Prints the verdict and the findings per seed.
Run from the repository root: ``python benchmarks/diagnose_noise_model_alone.py 0 8``.
"""
import sys
import jax; jax.config.update("jax_enable_x64", True)
import numpy as np, hbjax
sys_ = hbjax.default_system()
rows = []
for seed in range(int(sys.argv[1]), int(sys.argv[2])):
    rng = np.random.default_rng(seed)
    N = 3000
    v = np.repeat(rng.uniform(-6, 6, N // 10), rng.integers(5, 15))[:N]
    if v.size < N: v = np.resize(v, N)
    y = np.asarray(hbjax.simulate(sys_, v, 0.05 * rng.standard_normal(N)))
    pole = rng.uniform(0.98, 0.998)
    gain = rng.uniform(0.5, 2.0) * (1 - pole) * 0.4
    kind = ["square", "abs", "cube"][seed % 3]
    f = {"square": v * np.abs(v), "abs": np.abs(v) * 3, "cube": v ** 3 / 6}[kind]
    extra = np.asarray(hbjax.simulate(hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [0.0, 1.0]), hbjax.ARX([-pole], [1.0])), gain * f))
    rho = rng.uniform(0.8, 0.95)
    noise = np.convolve(rng.standard_normal(N), 0.3 * rho ** np.arange(80))[:N]
    for name, yy in (("input-driven " + kind, y + extra), ("coloured noise", y + noise)):
        d = hbjax.diagnose(sys_, v, yy, effects=["colored_noise"], progress=False, key=jax.random.key(seed))
        print(seed, name, d.verdict, [f.effect for f in d.findings], flush=True)
