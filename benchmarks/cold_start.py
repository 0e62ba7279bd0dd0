"""Cold starts: the first call of a fresh process, with hbjax's persistent compilation cache
empty (first process) and filled (second process), and the extra cost of a new record
length in a warm process.

Run: ``nice .venv/bin/python benchmarks/cold_start.py [--tree DIR]`` (writes its section of
RESULTS.md; ``--tree`` runs the package copy in DIR, e.g. a snapshot of a working tree).
Every measurement runs in its own ``python`` process with ``HBJAX_CACHE_DIR`` pointing at a
fresh temporary directory, so the user's cache is neither used nor touched. Timed: the call
itself (import excluded) for ``refine`` and ``diagnose``; the whole command (interpreter
start, imports, reading the CSV, fitting, writing the model) for the CLI.

- ``refine``: default system, random-level input, 2000 samples, equation noise 0.1, from a
  model 10% off the truth, static-gain normalisation.
- ``diagnose``: nominal default system against a recording of 5000 samples of the default
  system with a 15% larger gain of B (a parameter mismatch), all effects.
- CLI: ``hbjax identify fit --na 2 --nb 2 --m 3`` on the cascaded-tanks estimation record
  (1024 samples, ``uEst``/``yEst``), 32 starts.
- New length, warm process: ``simulate`` and ``refine`` at N = 5000 (compile), again at
  5000 (warm), then at N = 5001: the extra time over the warm call.
"""

import json
import os
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
    t0 = time.perf_counter()
    res = hbjax.refine(init, (v, y))
    jax.block_until_ready(res.model)
    print(json.dumps({"seconds": time.perf_counter() - t0}))
""")

DIAGNOSE = PRELUDE + textwrap.dedent("""
    truth = hbjax.default_system()
    truth = hbjax.Hammerstein(truth.backlash, hbjax.ARX(truth.arx.a, 1.15 * truth.arx.b))
    v, y = record(5000, seed=1, model=truth)
    t0 = time.perf_counter()
    d = hbjax.diagnose(hbjax.default_system(), v, y, progress=False)
    print(json.dumps({"seconds": time.perf_counter() - t0, "mismatch": bool(d.mismatch)}))
""")

NEW_LENGTH = PRELUDE + textwrap.dedent("""
    out = {}
    model = hbjax.default_system()
    v, y = record(7000, seed=2)  # another bucket: simulate at 5000 compiles afresh
    init = perturbed(model, 1.1)
    for name, call in (("simulate", lambda n: hbjax.simulate(model, v[:n])),
                       ("refine", lambda n: hbjax.refine(init, (v[:n], y[:n])).model)):
        times = []
        for n in (5000, 5000, 5001):
            t0 = time.perf_counter()
            jax.block_until_ready(call(n))
            times.append(time.perf_counter() - t0)
        out[name] = {"first": times[0], "warm": times[1], "new_length": times[2],
                     "extra": times[2] - times[1]}
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
    args = [PYTHON, "-m", "hbjax", "identify", "fit", "--na", "2", "--nb", "2",
            "--m", "3", str(TANKS), "--input", "uEst", "--output", "yEst",
            "--out", str(workdir / "tanks.json"), "--force"]
    t0 = time.perf_counter()
    env = _env(cache, disable)
    env["PYTHONPATH"] = str(TREE)
    out = subprocess.run(args, env=env, capture_output=True, text=True, timeout=1200,
                         cwd=workdir)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return time.perf_counter() - t0


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
        f"**{v['extra']:.3f}** | {'yes' if v['extra'] <= 1.0 else 'no'} |"
        for k, v in length.items())
    body = f"""
Machine: {describe()}. 1-minute load average {load0[0]:.1f} at the start and {load1[0]:.1f}
at the end, on {os.cpu_count()} cores shared with other work. One warm process, seconds;
"extra" = the call at the new length minus the warm call at the old one. `simulate` pads
eager records to length buckets (`docs/performance.md`): 5000 and 5001 samples both run the
program compiled for 5120. `refine` compiles per record length.

| call | first at N=5000 | warm at N=5000 | new N=5001 | extra | <= 1 s |
|---|---|---|---|---|---|
{ltable}
"""
    write_section("New record length in a warm process", body)
    print(body)


def main():
    if "--length-only" in sys.argv:
        return new_length()
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "cache"
        for name, target, run in (
            ("first `refine` (2000 samples)", 3.0, lambda d=False: child(REFINE, cache, d)["seconds"]),
            ("first `diagnose` (5000 samples)", 8.0, lambda d=False: child(DIAGNOSE, cache, d)["seconds"]),
            ("CLI `hbjax identify fit` on the tanks (wall)", 8.0, lambda d=False: cli(cache, tmp, d)),
        ):
            off = run(True) if NO_CACHE else float("nan")
            first = run()
            second = run()
            rows.append((name, off, first, second, target))
            print(f"{name}: no cache {off:.2f} s, empty cache {first:.2f} s, "
                  f"filled cache {second:.2f} s (target <= {target} s)", flush=True)
        files, mb = cache_size(cache)
    load1 = os.getloadavg()

    table = "\n".join(
        f"| {name} | {'-' if off != off else f'{off:.2f}'} | {first:.2f} | **{second:.2f}** | <= {target:g} | "
        f"{'yes' if second <= target else 'no'} |" for name, off, first, second, target in rows)
    body = f"""
Machine: {describe()}. 1-minute load average {load0[0]:.1f} at the start of this run and
{load1[0]:.1f} at the end, on {os.cpu_count()} cores shared with other work (timings under load
are inflated, roughly in proportion to load / cores; the ratios between columns are the
meaningful part). Script: `benchmarks/cold_start.py` (what each row runs is in its
docstring). Each number is one fresh `python` process; "no cache" runs with
`HBJAX_NO_COMPILATION_CACHE=1` (only with `--no-cache-runs`: it costs about as much as the
empty cache), "empty cache" is the first process with hbjax's cache on (it compiles and
writes), "filled cache" the second (it loads). The cache held {files} files,
{mb:.1f} MB, after these runs.

| first call in a fresh process | no cache (s) | empty cache (s) | filled cache (s) | target (s) | met |
|---|---|---|---|---|---|
{table}
"""
    write_section("Cold starts", body)
    print(body)
    new_length()


if __name__ == "__main__":
    main()
