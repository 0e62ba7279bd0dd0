"""Cold starts: the first call of a fresh process, with hbjax's persistent compilation cache
empty (first process) and filled (second process), and the extra cost of a new record
length in a warm process.

Run: ``.venv/bin/python benchmarks/cold_start.py [--tree DIR]`` (writes its sections of
RESULTS.md; ``--tree`` runs the package copy in DIR, e.g. a snapshot of a working tree).
Not under ``nice`` on a shared machine: a lowered priority measures the other work.
Every measurement runs in its own ``python`` process with ``HBJAX_CACHE_DIR`` pointing at a
fresh temporary directory, so the user's cache is neither used nor touched. Timed: the call
itself (import excluded) for ``refine`` and ``diagnose``; the whole command (interpreter
start, imports, reading the CSV, fitting, writing the model) for the CLI. Each timing
comes with the CPU time it took (``time.process_time`` of the child around the call, all
its threads; for the CLI ``getrusage(RUSAGE_CHILDREN)`` of the whole command), which a
loaded machine inflates far less than the wall time.

- ``refine``: default system, random-level input, 2000 samples, equation noise 0.1, from a
  model 10% off the truth, static-gain normalisation.
- ``diagnose``: nominal default system against a recording of 5000 samples of the default
  system with a 15% larger gain of B (a parameter mismatch), all effects.
- CLI: ``hbjax identify fit --na 2 --nb 2 --m 3`` on the cascaded-tanks estimation record
  (1024 samples, ``uEst``/``yEst``), 32 starts.
- New length, warm process: ``simulate``, ``refine`` and ``diagnose`` (nominal default
  system on a recording of a 10% different one) at N = 5000 (compile), again at 5000
  (warm), then at N = 5001 and N = 4900 (same buckets: 5120 for the record, 3584 for
  the diagnosis's fitting part): the extra time of the new length over the warm call.
"""

import json
import os
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

from _machine import describe, write_section  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
TREE = Path(sys.argv[sys.argv.index("--tree") + 1]) if "--tree" in sys.argv else ROOT
NO_CACHE = "--no-cache-runs" in sys.argv  # also time each first call with the cache off
TANKS = ROOT / "hbjax" / "data" / "cascaded_tanks" / "dataBenchmark.csv"

PRELUDE = textwrap.dedent("""
    import json, time
    import numpy as np
    import jax
    jax.config.update("jax_enable_x64", True)
    import hbjax

    def record(n, seed=0, model=None, noise=0.1):
        rng = np.random.default_rng(seed)
        v = np.repeat(rng.uniform(-8, 8, n), rng.integers(1, 20, n))[:n]
        model = model or hbjax.default_system()
        return v, np.asarray(hbjax.simulate(model, v, noise * rng.standard_normal(n)))

    def perturbed(model, factor):
        return jax.tree_util.tree_map(lambda x: x * factor, model)
""")

REFINE = PRELUDE + textwrap.dedent("""
    v, y = record(2000)
    init = perturbed(hbjax.default_system(), 1.1)
    t0, c0 = time.perf_counter(), time.process_time()
    res = hbjax.refine(init, (v, y))
    jax.block_until_ready(res.model)
    print(json.dumps({"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0}))
""")

DIAGNOSE = PRELUDE + textwrap.dedent("""
    truth = hbjax.default_system()
    truth = hbjax.Hammerstein(truth.backlash, hbjax.ARX(truth.arx.a, 1.15 * truth.arx.b))
    v, y = record(5000, seed=1, model=truth)
    t0, c0 = time.perf_counter(), time.process_time()
    d = hbjax.diagnose(hbjax.default_system(), v, y, progress=False)
    print(json.dumps({"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0,
                      "mismatch": bool(d.mismatch)}))
""")

NEW_LENGTH = PRELUDE + textwrap.dedent("""
    out = {}
    model = hbjax.default_system()
    v, y = record(7000, seed=2)  # another bucket: simulate at 5000 compiles afresh
    init = perturbed(model, 1.1)
    def diagnosed(n):
        hbjax.diagnose(model, v[:n], y[:n], progress=False)
        return jax.numpy.zeros(())  # diagnose returns host data: nothing left to wait for

    for name, call in (("simulate", lambda n: hbjax.simulate(model, v[:n])),
                       ("refine", lambda n: hbjax.refine(init, (v[:n], y[:n])).model),
                       ("diagnose", diagnosed)):
        times, cpu = [], []
        for n in (5000, 5000, 5001, 4900):
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(call(n))
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        out[name] = {"first": times[0], "warm": times[1], "new_length": times[2],
                     "extra": times[2] - times[1], "other_length": times[3],
                     "extra_cpu": cpu[2] - cpu[1], "extra_other": times[3] - times[1]}
    print(json.dumps(out))
""")


def _env(cache, disable=False):
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "HBJAX_NO_COMPILATION_CACHE")}
    env.update(JAX_PLATFORMS="cpu", HBJAX_CACHE_DIR=str(cache), PYTHONWARNINGS="ignore")
    if disable:
        env["HBJAX_NO_COMPILATION_CACHE"] = "1"
    return env


def child(code, cache, disable=False):
    out = subprocess.run([PYTHON, "-c", code], env=_env(cache, disable), capture_output=True,
                         text=True, timeout=1200, cwd=TREE)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def cli(cache, workdir, disable=False):
    """``(wall seconds, CPU seconds)`` of the whole command."""
    args = [PYTHON, "-m", "hbjax", "identify", "fit", "--na", "2", "--nb", "2",
            "--m", "3", str(TANKS), "--input", "uEst", "--output", "yEst",
            "--out", str(workdir / "tanks.json"), "--force"]
    env = _env(cache, disable)
    env["PYTHONPATH"] = str(TREE)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(args, env=env, capture_output=True, text=True, timeout=1200,
                         cwd=workdir)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def cache_size(path):
    files = [p for p in Path(path).rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files) / 1e6


def new_length():
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        length = child(NEW_LENGTH, Path(tmp) / "cache")
    load1 = os.getloadavg()
    print(json.dumps(length, indent=1), flush=True)
    ltable = "\n".join(
        f"| `{k}` | {v['first']:.2f} | {v['warm']:.3f} | {v['new_length']:.3f} | "
        f"**{v['extra']:.3f}** | {v['extra_cpu']:.3f} | {v['other_length']:.3f} | "
        f"{'yes' if max(v['extra'], v['extra_other']) <= 1.0 else 'no'} |"
        for k, v in length.items())
    body = f"""
Machine: {describe()}. 1-minute load average {load0[0]:.1f} at the start and {load1[0]:.1f}
at the end, on {os.cpu_count()} cores shared with other work. One warm process, seconds;
"extra" = the call at the new length minus the warm call at the old one (wall; CPU in the
next column). Eager calls pad their records to length buckets (`docs/performance.md`):
4900, 5000 and 5001 samples all run the program compiled for 5120. `refine` carries the
recorded length as a runtime value and masks the padded samples out of the residuals, the
Gram matrix, the band checks, the sample count and the fit figures; its results equal the
unpadded ones (`tests/test_refine_buckets.py`). `diagnose` pads its fitting part (3584)
and its whole record the same way, with the criterion's window a runtime value
(`tests/test_diagnose_buckets.py`).

| call | first at N=5000 | warm at N=5000 | new N=5001 | extra | extra CPU | new N=4900 | <= 1 s |
|---|---|---|---|---|---|---|---|
{ltable}
"""
    write_section("New record length in a warm process", body)
    print(body)


def _fmt(pair):
    wall, cpu = pair
    return "-" if wall != wall else f"{wall:.2f} ({cpu:.2f})"


def main():
    if "--length-only" in sys.argv:
        return new_length()
    load0 = os.getloadavg()
    rows = []

    def call(code, cache, disable):
        out = child(code, cache, disable)
        return out["seconds"], out["cpu"]

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "cache"
        for name, target, run in (
            ("first `refine` (2000 samples)", 3.0, lambda d=False: call(REFINE, cache, d)),
            ("first `diagnose` (5000 samples)", 8.0, lambda d=False: call(DIAGNOSE, cache, d)),
            ("CLI `hbjax identify fit` on the tanks (wall)", 8.0, lambda d=False: cli(cache, tmp, d)),
        ):
            off = run(True) if NO_CACHE else (float("nan"), float("nan"))
            first = run()
            load = os.getloadavg()[0]
            second = run()
            rows.append((name, off, first, second, target, load))
            print(f"{name}: no cache {_fmt(off)} s, empty cache {_fmt(first)} s, "
                  f"filled cache {_fmt(second)} s (wall (CPU); target <= {target} s; "
                  f"load {load:.1f})", flush=True)
        files, mb = cache_size(cache)
    load1 = os.getloadavg()

    table = "\n".join(
        f"| {name} | {_fmt(off)} | {_fmt(first)} | **{second[0]:.2f}** ({second[1]:.2f}) | "
        f"{load:.1f} | <= {target:g} | {'yes' if second[0] <= target else 'no'} "
        f"(CPU: {'yes' if second[1] <= target else 'no'}) |"
        for name, off, first, second, target, load in rows)
    body = f"""
Machine: {describe()}. 1-minute load average {load0[0]:.1f} at the start of this run and
{load1[0]:.1f} at the end, on {os.cpu_count()} cores shared with other work (wall times under
load are inflated, roughly in proportion to load / cores; the CPU times in parentheses --
all threads of the measured process, `time.process_time` around the call, or
`getrusage(RUSAGE_CHILDREN)` of the whole CLI command -- much less so). Script:
`benchmarks/cold_start.py` (what each row runs is in its docstring). Each number is one
fresh `python` process; "no cache" runs with `HBJAX_NO_COMPILATION_CACHE=1` (only with
`--no-cache-runs`: it costs about as much as the empty cache), "empty cache" is the first
process with hbjax's cache on (it compiles and writes), "filled cache" the second (it
loads). The cache held {files} files, {mb:.1f} MB, after these runs.

| first call in a fresh process | no cache, s (CPU s) | empty cache, s (CPU s) | filled cache, s (CPU s) | load at the filled run | target (s) | met |
|---|---|---|---|---|---|---|
{table}
"""
    write_section("Cold starts", body)
    print(body)
    new_length()


if __name__ == "__main__":
    main()
