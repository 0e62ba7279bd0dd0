#!/usr/bin/env bash
# The simulator and Monte Carlo benchmarks on an accelerator (a CUDA GPU), printing only:
# RESULTS.md's sections are written by the CPU runs. Uses the machine's own jax, equinox,
# optimistix, numba and tqdm, with the package from this checkout on PYTHONPATH.
# Run from the repository root: `bash benchmarks/accelerator.sh OUTDIR`.
set -u
out=${1:-accelerator_output}
mkdir -p "$out" && out=$(cd "$out" && pwd)
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
nvidia-smi -L | tee "$out/machine.txt"
python3 -c "import jax, numba; print('jax', jax.__version__, jax.devices(), 'numba', numba.__version__)" | tee -a "$out/machine.txt"
cd benchmarks
# Default batch (as on the CPU), then a batch large enough to fill the GPU.
timeout 120 python3 simulate.py --no-write --batch 1000 2>&1 | tee "$out/simulate_1000.txt"
timeout 150 python3 simulate.py --no-write --batch 20000 --repeats 3 2>&1 | tee "$out/simulate_20000.txt"
# Monte Carlo with the accelerator's default chunk, then a study ten times larger.
timeout 150 python3 monte_carlo.py --platform cuda --skip-memory 2>&1 | tee "$out/monte_carlo_1000.txt"
timeout 150 python3 monte_carlo.py --platform cuda --skip-memory --realisations 10000 --numpy-subset 3 2>&1 | tee "$out/monte_carlo_10000.txt"
# Without the CPU backend the closed form's host callback cannot run: a clear error, not JAX's.
JAX_PLATFORMS=cuda timeout 60 python3 -c "
import jax; jax.config.update('jax_enable_x64', True); import hbjax
try:
    hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.1, lengths=[2000], realisations=4, key=jax.random.key(0), progress=False)
    print('JAX_PLATFORMS=cuda: ran')
except RuntimeError as e:
    print('JAX_PLATFORMS=cuda:', e)
" 2>&1 | tail -2 | tee "$out/cuda_only.txt"
