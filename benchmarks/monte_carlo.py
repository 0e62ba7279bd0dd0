"""Monte Carlo study throughput: hbjax.monte_carlo vs plain NumPy vs Numba (parallel).

The task: R realisations of the full three-experiment closed-form identification (draw white
equation noise for v1, v2, v3; simulate the HB-Hammerstein system; estimate offset, least
squares (26) with its transient search, Vandermonde solves (45)-(46), diagnostics and result
codes) with T samples per experiment, on the default system. All three sides run the same
algorithm (benchmarks/_mc_peers.py mirrors hbjax._identify.giri.estimate_giri step by step); each draws
its own noise with its native generator. Then the peak memory of a 10 000 x 100 000 study.

Run: ``.venv/bin/python benchmarks/monte_carlo.py`` (writes its section of RESULTS.md).
Options: ``--realisations 1000 --length 10000 --numpy-subset 10 --skip-memory``.
"""

import argparse
import json
import os
import subprocess
import sys
import textwrap
import time

import jax
jax.config.update("jax_enable_x64", True)  # the estimators and the peers compare in float64
import numpy as np

import hbjax

sys.path.insert(0, os.path.dirname(__file__))
import _mc_peers as peers  # noqa: E402
from _machine import describe, write_section  # noqa: E402


NOISE_STD = 0.1

# One JAX configuration in a fresh process: `devices` host devices (XLA_FLAGS), a warm-up
# study (compilation) and `repeats` timed studies reusing the compiled chunk.
_JAX_SCRIPT = textwrap.dedent("""
    import json, sys, time, jax, numpy as np, hbjax
    jax.config.update("jax_enable_x64", True)
    R, T, repeats = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    chunk = int(sys.argv[4]) or None
    m, d = hbjax.default_system(), hbjax.default_design()
    def study(seed):
        return hbjax.monte_carlo(m, d, noise_std=%r, lengths=[T], realisations=R,
                                 key=jax.random.key(seed), progress=False, keep_estimates=True,
                                 chunk_size=chunk)
    t0 = time.perf_counter(); first = study(0); wall_first = time.perf_counter() - t0
    runs = []
    for k in range(repeats):
        t0 = time.perf_counter(); s = study(1 + k); runs.append(time.perf_counter() - t0)
    json.dump(dict(devices=len(jax.devices()), compile=float(first.compile_seconds[0]),
                   wall_first=wall_first, runs=runs, chunk=int(s.chunk_size),
                   rmse=s.rmse[0].tolist(), n_valid=int(s.n_valid[0]),
                   theta0=first.estimates[0, 0].tolist()), sys.stdout)
""" % NOISE_STD)

# Peak resident memory from /proc/self/status VmHWM (this process only: ru_maxrss of a
# child started by fork/exec can carry the parent's high-water mark).
_MEMORY_SCRIPT = textwrap.dedent("""
    import json, re, sys, time, jax, hbjax
    jax.config.update("jax_enable_x64", True)
    def hwm_kib():
        return int(re.search(r"VmHWM:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
    R, T = int(sys.argv[1]), int(sys.argv[2])
    m, d = hbjax.default_system(), hbjax.default_design()
    base = hwm_kib()
    t0 = time.perf_counter()
    s = hbjax.monte_carlo(m, d, noise_std=%r, lengths=[T], realisations=R,
                          key=jax.random.key(0), progress=False)
    wall = time.perf_counter() - t0
    peak = hwm_kib()
    json.dump(dict(peak_kib=peak, base_kib=base, wall=wall, chunk=int(s.chunk_size),
                   n_valid=int(s.n_valid[0]), compile=float(s.compile_seconds[0]),
                   slope_rmse=s.rmse[0].tolist()), sys.stdout)
""" % NOISE_STD)


def run_jax(R, T, devices, repeats=3, platform="cpu", chunk_size=None):
    if platform == "cpu":
        env = dict(os.environ, JAX_PLATFORMS="cpu",
                   XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    else:
        # The accelerator's devices, with the host's CPU listed too: the closed form's band
        # projection is a host callback, which needs a CPU device. The parent process holds
        # the GPU too, so neither may preallocate most of its memory.
        env = dict(os.environ, JAX_PLATFORMS=f"{platform},cpu",
                   XLA_PYTHON_CLIENT_PREALLOCATE="false")
    out = subprocess.run([sys.executable, "-c", _JAX_SCRIPT, str(R), str(T), str(repeats),
                          str(chunk_size or 0)],
                         env=env, capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"the hbjax study failed ({platform}, devices {devices or 'all'}):\n"
                           f"{out.stderr}")
    return json.loads(out.stdout)


def run_memory(R, T, timeout):
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _MEMORY_SCRIPT, str(R), str(T)], env=env,
                         check=True, capture_output=True, text=True, timeout=timeout)
    return json.loads(out.stdout)


def agreement(model, design, s, T, n_check=3):
    """Same noise records into the three implementations: max |difference| of estimates."""
    import jax.numpy as jnp

    from hbjax._identify.giri import estimate_giri

    rng = np.random.default_rng(7)
    worst_nb, worst_np = 0.0, 0.0
    for _ in range(n_check):
        xi = NOISE_STD * rng.standard_normal((3, T))
        ys = [hbjax.simulate(model, s["v"][e], xi[e]) for e in range(3)]
        ref = np.asarray(hbjax.flatten_params(estimate_giri(design, *map(jnp.asarray, ys)).model))
        nb, _ = peers.numba_one(*_nb_args(s), xi)
        y_np = [peers.numpy_simulate(s["c1"], s["c2"], s["a"], s["b"], s["v"][e], xi[e])
                for e in range(3)]
        th_np, _ = peers.numpy_estimate(s, *y_np)
        worst_nb = max(worst_nb, np.max(np.abs(nb - ref)))
        worst_np = max(worst_np, np.max(np.abs(th_np - ref)))
    return worst_nb, worst_np


def _nb_args(s):
    return (s["c1"], s["c2"], s["a"], s["b"], s["v"], s["u2"], s["t_inst"], s["j_inst"],
            s["levels"], s["n"], s["m"], s["h_m"])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realisations", type=int, default=1000)
    parser.add_argument("--length", type=int, default=10_000)
    parser.add_argument("--numpy-subset", type=int, default=10)
    parser.add_argument("--memory-realisations", type=int, default=10_000)
    parser.add_argument("--memory-length", type=int, default=100_000)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--no-write", action="store_true")
    parser.add_argument("--platform", default="cpu",
                        help="JAX platform of the hbjax side: cpu (1 and one host device per "
                        "core) or an accelerator (cuda: its devices); a non-cpu run prints only")
    parser.add_argument("--chunk-size", type=int, default=None,
                        help="realisations per device per chunk (default: hbjax's, by length)")
    args = parser.parse_args()
    if args.platform != "cpu":
        args.no_write = True  # the RESULTS.md section describes the CPU run
    R, T = args.realisations, args.length
    load_before = os.getloadavg()[0]
    model, design = hbjax.default_system(), hbjax.default_design()
    s = peers.setup(model, design, T)
    cores = os.cpu_count()
    print(describe())

    # --- hbjax: default (1 CPU device) and one host device per core (sharded chunks).
    jax_runs = {}
    # On an accelerator: its own devices, however many (the count comes back with the run).
    for count in sorted({1, cores}) if args.platform == "cpu" else [None]:
        res = run_jax(R, T, count, platform=args.platform, chunk_size=args.chunk_size)
        dev = res["devices"]
        jax_runs[dev] = res
        print(f"hbjax, {dev} device(s): compile {res['compile']:.2f} s, runs "
              f"{', '.join(f'{x:.3f}' for x in res['runs'])} s (chunk {res['chunk']}/device)")

    # --- Numba, prange over realisations on all cores.
    t0 = time.perf_counter()
    peers.numba_study(*_nb_args(s), 4, NOISE_STD, 0)
    nb_compile = time.perf_counter() - t0
    nb_runs = []
    for k in range(3):
        t0 = time.perf_counter()
        nb_est, nb_codes = peers.numba_study(*_nb_args(s), R, NOISE_STD, 1000 * (k + 1))
        nb_runs.append(time.perf_counter() - t0)
    import numba

    print(f"numba parallel ({numba.get_num_threads()} threads): compile/first call "
          f"{nb_compile:.2f} s, runs {', '.join(f'{x:.3f}' for x in nb_runs)} s")

    # --- plain NumPy, loop over realisations (timed on a subset, extrapolated).
    t0 = time.perf_counter()
    np_est, np_codes = peers.numpy_study(s, args.numpy_subset, NOISE_STD, 0)
    np_sub = time.perf_counter() - t0
    np_full = np_sub * R / args.numpy_subset
    print(f"numpy loop: {args.numpy_subset} realisations in {np_sub:.2f} s -> "
          f"{np_full:.1f} s for {R} (extrapolated)")

    # --- agreement: identical noise in, estimates out; and the statistics of the studies.
    d_nb, d_np = agreement(model, design, s, T)
    true = np.asarray(hbjax.flatten_params(hbjax.normalise(model, design.h_m)))
    jax_rmse = np.asarray(jax_runs[1]["rmse"])
    ok = nb_codes == 0
    nb_rmse = np.sqrt(((nb_est[ok] - true) ** 2).mean(axis=0))
    rmse_ratio = nb_rmse / jax_rmse
    print(f"agreement on identical noise: max |numba - hbjax| = {d_nb:.2e}, "
          f"max |numpy - hbjax| = {d_np:.2e}")
    print(f"RMSE numba/hbjax per parameter (independent draws, R={R}): "
          f"{np.round(rmse_ratio, 3).tolist()}")

    best = {dev: min(r["runs"]) for dev, r in jax_runs.items()}
    dev_best = min(best, key=best.get)
    jax_t, nb_t = best[dev_best], min(nb_runs)
    lines = [
        f"hbjax {dev}-device: {best[dev]:.3f} s ({R / best[dev]:.0f} realisations/s)"
        for dev in sorted(best)
    ]
    print(*lines, sep="\n")
    print(f"speed-up vs numpy: {np_full / jax_t:.1f}x (target >= 50x); "
          f"vs numba parallel: {nb_t / jax_t:.2f}x (target >= 1x)")

    # --- peak memory of a large study, in a fresh process.
    mem = None
    if not args.skip_memory:
        mem = run_memory(args.memory_realisations, args.memory_length, timeout=1500)
        print(f"memory study {args.memory_realisations} x {args.memory_length}: peak RSS "
              f"{mem['peak_kib'] / 2**20:.2f} GiB (after import {mem['base_kib'] / 2**20:.2f} GiB),"
              f" {mem['wall']:.0f} s, chunk {mem['chunk']}/device, {mem['n_valid']} valid")

    load_after = os.getloadavg()[0]
    print(f"1-minute load average: {load_before:.1f} at start, {load_after:.1f} at end")
    if args.no_write:
        return
    jax_rows = "\n".join(
        f"| hbjax.monte_carlo, {dev} CPU device(s){' (XLA_FLAGS host devices)' if dev > 1 else ''}"
        f" | {jax_runs[dev]['compile']:.2f} | {best[dev]:.3f} | {R / best[dev]:.0f} |"
        f" {np_full / best[dev]:.0f}x | {nb_t / best[dev]:.2f}x |"
        for dev in sorted(best)
    )
    body = f"""
Machine: {describe()}. Default system and design (n=2, m=3, h_m=4), white equation noise
std {NOISE_STD}, **{R} realisations x 3 experiments x T = {T} samples**, full closed-form
identification (offset with transient search, LS (26), Vandermonde (45)-(46), diagnostics and
result codes). Best of 3 runs after compilation. 1-minute load average {load_before:.1f} at
the start of this run and {load_after:.1f} at the end, on {cores} cores (timings under load are
noisy); all sides ran under the same conditions.

| implementation | compile (s) | run (s) | realisations/s | vs NumPy | vs Numba parallel |
|---|---|---|---|---|---|
{jax_rows}
| Numba `@njit(parallel=True)`, prange over realisations, {numba.get_num_threads()} threads | {nb_compile:.1f} (first call) | {nb_t:.3f} | {R / nb_t:.0f} | {np_full / nb_t:.0f}x | 1.00x |
| plain NumPy, loop over realisations | - | {np_full:.1f} (extrapolated from {args.numpy_subset}) | {R / np_full:.1f} | 1x | {nb_t / np_full:.3f}x |

Targets: >= 50x NumPy (measured {np_full / jax_t:.0f}x), >= Numba parallel (measured
{nb_t / jax_t:.2f}x, best hbjax configuration: {dev_best} device(s)).

What each side does: hbjax draws threefry float32 normals (used in float64) per realisation,
simulates the three experiments with the jitted `lax.scan` (vmapped: realisations on the
minor axis of time-major arrays; the play operator does not depend on the noise, so vmap
keeps it unbatched) and runs `hbjax._identify.giri.estimate_giri` vmapped, in chunks sharded over
the devices. Numba: per realisation (prange), `np.random.standard_normal` (thread-local,
seeded per realisation), one loop simulating play + ARX, the normal equations accumulated
in one pass (no regressor matrix), LAPACK for the 4x4/3x3 solves. NumPy: per realisation,
a Python loop over time for the simulation and vectorised NumPy for the estimation.
Agreement on identical noise records: max |Numba - hbjax| = {d_nb:.1e}, max
|NumPy - hbjax| = {d_np:.1e}; RMSE ratio Numba/hbjax over independent draws:
{np.round(rmse_ratio, 2).tolist()}.
"""
    if mem is not None:
        body += f"""
Peak memory of a {args.memory_realisations} x {args.memory_length} study (realisations x
samples per experiment, 3 x {args.memory_realisations * args.memory_length:.1e} simulated
samples), fresh process, peak resident set (`VmHWM`): **{mem['peak_kib'] / 2**20:.2f} GiB** (target < 2 GB;
{mem['base_kib'] / 2**20:.2f} GiB after importing hbjax), {mem['wall']:.0f} s wall, chunks of
{mem['chunk']} realisations per device, {mem['n_valid']} valid realisations.
"""
    write_section("Monte Carlo", body)


if __name__ == "__main__":
    main()
