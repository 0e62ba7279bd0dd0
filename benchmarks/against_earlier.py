"""The package against an earlier version of itself: the same public calls, the same data,
timed warm on the same machine in one run, so that a refactoring's cost (or a new check's)
is measured rather than inferred from figures taken on other machines at other loads.

Run: ``.venv/bin/python benchmarks/against_earlier.py [--rounds N] [--calls refine,fit] [COMMIT ...]`` (default: the last
commit of the flat, pre-subpackage layout, against the working tree). Each commit is
checked out into a temporary git worktree; a child process per version and round imports
that tree's ``hbjax`` and times:

- ``simulate``: ``jax.jit(jax.vmap(simulate))`` of the default system on 200 inputs of
  10 000 samples;
- ``refine``: the public ``hbjax.refine`` (eager, checks included) from the closed form on
  the paper's three experiments, T = 10 000 each, noise std 0.2 (5 noise draws);
- ``fit``: the public ``hbjax.fit`` (eager, 32 starts) on one staircase record of 4000
  samples, ``(na, nb, m) = (2, 2, 3)``;
- ``monte_carlo``: a closed-form study, 2 lengths x 200 realisations;
- ``diagnose``: the public ``hbjax.diagnose`` of the default model on 5000 samples;
- ``diagnose_common``: the same with ``effects=`` the flat layout's candidates whose
  definition has not changed since (all but ``coulomb_friction``), which separates the
  engine's cost from that of the candidates added after it.

Each call is run once to compile, then best of 3 (``simulate`` and ``refine``, a few ms
each: best of 15, ``refine`` the median over the draws; ``monte_carlo``: best of 5; on this
shared 2-core machine a single call varies by tens of percent); rounds alternate the versions and the table reports the median over
rounds, and the ratio later / earlier (above 1: slower). Calls whose defaults do more work
in the later version are listed as such below the table.
"""

import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from _machine import describe, write_section

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The last commit with the flat module layout (hbjax/_refine.py, hbjax/_diagnose.py, ...).
FLAT_LAYOUT = "f15f477"
ROUNDS = 3
# What the child times (`--calls` takes a comma-separated subset; diagnose brings
# diagnose_common with it).
CALLS = ["simulate", "refine", "fit", "monte_carlo", "diagnose"]

CHILD = r'''
import json, sys, time
tree = sys.argv[1]
wanted = set(sys.argv[2].split(","))
sys.path.insert(0, tree)
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import hbjax
assert hbjax.__file__.startswith(tree), hbjax.__file__

def best(f, repeat=3):
    jax.block_until_ready(f())
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f())
        out.append(time.perf_counter() - t0)
    return min(out)

system, design = hbjax.default_system(), hbjax.default_design()
times = {}

if "simulate" in wanted:
    v = jax.random.uniform(jax.random.PRNGKey(0), (200, 10_000), minval=-4.0, maxval=4.0)
    sim = jax.jit(jax.vmap(lambda x: hbjax.simulate(system, x)))
    times["simulate"] = best(lambda: sim(v), repeat=15)

if "refine" in wanted:
    T = 10_000
    inputs = [np.asarray(f(T)) for f in (design.constant_input, design.binary_input,
                                           design.staircase_input)]
    per_draw = []
    for key in jax.random.split(jax.random.PRNGKey(100), 5):
        ys = [np.asarray(hbjax.simulate(system, x, 0.2 * jax.random.normal(k, (T,))))
              for x, k in zip(inputs, jax.random.split(key, 3))]
        start = hbjax.identify_giri(design, *ys).model
        recs = list(zip(inputs, ys))
        per_draw.append(best(lambda: hbjax.refine(start, recs, h_m=4.0).model.arx.a, repeat=15))
    times["refine"] = float(np.median(per_draw))

if "fit" in wanted:
    x = np.asarray(design.staircase_input(4000))
    y = np.asarray(hbjax.simulate(system, x, 0.1 * jax.random.normal(jax.random.PRNGKey(5), (4000,))))
    times["fit"] = best(lambda: hbjax.fit([(x, y)], na=2, nb=2, m=3,
                                          key=jax.random.PRNGKey(1)).model.arx.a)

if "monte_carlo" in wanted:
    times["monte_carlo"] = best(lambda: jnp.asarray(hbjax.monte_carlo(
        system, design, noise_std=0.2, lengths=(1000, 4000), realisations=200,
        key=jax.random.PRNGKey(2)).rmse), repeat=5)

if "diagnose" in wanted:
    xd = np.asarray(jnp.sin(jnp.arange(5000) / 40.0) * 3.0
                    + jax.random.normal(jax.random.PRNGKey(3), (5000,)))
    yd = np.asarray(hbjax.simulate(system, xd, 0.05 * jax.random.normal(jax.random.PRNGKey(4), (5000,))))
    times["diagnose"] = best(lambda: jnp.asarray(len(hbjax.diagnose(system, xd, yd).findings)),
                             repeat=2)
    # The same candidate effects in both versions: those of the flat layout whose definition
    # did not change since (its coulomb_friction was a static term of the input; it now acts
    # inside the recursion), so the ratio measures the engine rather than the added candidates.
    COMMON = ["parameter_mismatch", "output_saturation", "input_saturation", "extra_delay",
              "unmodeled_dynamics", "colored_noise", "offset_drift", "parameter_change",
              "periodic_disturbance", "output_nonlinearity", "branch_degree"]
    times["diagnose_common"] = best(lambda: jnp.asarray(len(hbjax.diagnose(
        system, xd, yd, effects=COMMON).findings)), repeat=2)
print("RESULT " + json.dumps(times))
'''


def worktree(commit, parent):
    path = os.path.join(parent, commit)
    subprocess.run(["git", "-C", ROOT, "worktree", "add", "--detach", "-f", path, commit],
                   check=True, capture_output=True)
    return path


def run_child(tree, calls):
    env = dict(os.environ, HBJAX_NO_COMPILATION_CACHE="1")
    out = subprocess.run([sys.executable, "-c", CHILD, tree, ",".join(calls)],
                         capture_output=True, text=True,
                         env=env, cwd=tree, check=False)
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(f"{tree}: {out.stderr[-2000:]}")


def main():
    import numpy as np

    args = sys.argv[1:]
    rounds = ROUNDS
    if "--rounds" in args:
        i = args.index("--rounds")
        rounds = int(args[i + 1])
        del args[i:i + 2]
    calls = CALLS
    if "--calls" in args:
        i = args.index("--calls")
        calls = args[i + 1].split(",")
        unknown = sorted(set(calls) - set(CALLS))
        if unknown:
            raise SystemExit(f"--calls: unknown {unknown}; expected some of {CALLS}")
        del args[i:i + 2]
    earlier = args or [FLAT_LAYOUT]
    head = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True, check=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "hbjax"],
                           capture_output=True, text=True, check=True).stdout.strip()
    current = f"{head}{' + changes' if dirty else ''} (working tree)"
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        trees = {c: worktree(c, tmp) for c in earlier}
        trees[current] = ROOT
        results = {name: [] for name in trees}
        try:
            for r in range(rounds):
                for name, tree in trees.items():
                    results[name].append(run_child(tree, calls))
                    print(f"round {r + 1} {name}: " + ", ".join(
                        f"{k} {v * 1e3:.1f} ms" for k, v in results[name][-1].items()),
                        flush=True)
        finally:
            for path in trees.values():
                if path != ROOT:
                    subprocess.run(["git", "-C", ROOT, "worktree", "remove", "--force", path],
                                   capture_output=True, check=False)
    load.append(os.getloadavg()[0])
    timed = list(results[current][0])
    med = {name: {k: float(np.median([r[k] for r in rs])) for k in timed}
           for name, rs in results.items()}
    base = med[earlier[0]]
    later = [n for n in med if n != earlier[0]]
    lines = [
        (f"Machine: {describe()}. 1-minute load average {load[0]:.1f} at the start and "
         f"{load[1]:.1f} at the end. Warm times (compilation excluded), median over "
         f"{rounds} rounds that alternate the versions; ratios = later / {earlier[0]} "
         "(above 1: slower). Target (architecture issue): no slowdown beyond 10 %."),
        "",
        ("| call | " + " | ".join(f"{n} (ms)" for n in med) + " | "
         + " | ".join(f"ratio {n.split()[0]}" for n in later) + " |"),
        "|---|" + "---|" * (len(med) + len(later)),
    ]
    for k in timed:
        lines.append(f"| {k} | " + " | ".join(f"{med[n][k] * 1e3:.1f}" for n in med) + " | "
                     + " | ".join(f"{med[n][k] / base[k]:.2f}" for n in later) + " |")
    # The spread: each round's own ratio (same round, versions run one after the other).
    lines += ["", "Ratio in each round (later / earlier, round by round): " + "; ".join(
        f"{k} " + ", ".join(f"{b[k] / a[k]:.2f}" for a, b in
                            zip(results[earlier[0]], results[later[0]])) for k in timed) + "."]
    lines += [
        "",
        ("Work the working tree does that the earlier version did not, in these calls: "
         "`simulate` refuses an overflowing output (one `eqx.error_if` over the result); "
         "`refine` also solves on the core operator where the labelled optimum does not end "
         "on it, pads eager records to length buckets (no recompilation for a new length) and "
         "checks stability, the free-run fit on every record, identifiability and the "
         "residual tests (an input-effect test on every result; whiteness and independence "
         "where the free-run fit is below the floor); `fit` "
         "estimates the initial state (its default, `initial_state=\"estimate\"`), refines "
         "its best start on the core operator where its branches meet inside the data, "
         "solves a quarter of its starts (loops closed inside the data) on the core "
         "operator, and runs the same checks; `monte_carlo` computes every realisation in a "
         "group (one vmap) whose width is fixed by the record length (at most 32 realisations "
         "on CPU), so that every realisation gets the same bits "
         "whatever the number of realisations or devices; `diagnose` fits more candidate "
         "effects (physics inside the dynamics, harmonic distortion, level dependence), "
         "chooses an excited held-out part and validates findings by free-run simulation; with "
         "the common candidates (`diagnose_common`) it also fits the anchored variants "
         "(base held at the nominal values) of the anchorable effects."),
    ]
    body = "\n".join(lines)
    print(body)
    if calls != CALLS:  # a partial run is printed, not recorded over the full one
        return
    write_section("Against the flat-layout version (benchmarks/against_earlier.py)", body)


if __name__ == "__main__":
    main()
