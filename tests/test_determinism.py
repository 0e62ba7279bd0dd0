"""Same key, same bits: across calls, across processes, and across 1 vs 4 host devices.

A job (``JOB`` below) computes a set of results from fixed PRNG keys and prints a SHA-256 of
each result's bytes. It runs in this process and in subprocesses with 1 and with 4 host
devices (``XLA_FLAGS=--xla_force_host_platform_device_count=4``); on 4 devices the batched
work is sharded (``jax.pmap`` and a ``NamedSharding`` over the batch axis), on 1 device it is
not. All digests must agree. Reductions (the estimators' sums and factorizations) are
bitwise reproducible for a fixed per-device batch shape, so the batches are cut into
per-device chunks of a fixed size. Covered: the simulator, the closed form and the closed
form followed by vmapped Levenberg-Marquardt refinement. (``tests/test_monte_carlo.py`` covers ``hbjax.monte_carlo``.)
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

JOB = r'''
import hashlib, json
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
import hbjax
from hbjax._identify.giri import estimate_giri
from hbjax._identify.refine import refine_traceable

model, design = hbjax.default_system(), hbjax.default_design()
T, B = 600, 8
key = jax.random.key(20240607)
digests = {}

def digest(name, tree):
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(tree):
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    digests[name] = h.hexdigest()

# Single trajectories through the public, eagerly checked entry points.
noise = 0.1 * jax.random.normal(jax.random.fold_in(key, 0), (3, T))
inputs = [design.constant_input(T), design.binary_input(T), design.staircase_input(T)]
ys = [hbjax.simulate(model, v, xi) for v, xi in zip(inputs, noise)]
digest("noise", noise)
digest("simulate", ys)
digest("predict", hbjax.predict(model, inputs[2], ys[2]))
digest("play", hbjax.play(model.backlash, inputs[2]))
res = hbjax.identify_giri(design, *ys)
digest("identify_giri", (hbjax.flatten_params(res.model), res.offset, res.cond_ls, res.gap))

# Batches: B realisations of the three experiments, P per device per call. XLA may sum in a
# different order for a different batch shape, so bitwise equality across device counts is
# asked of the same per-device shape (as hbjax.monte_carlo does); the simulator has no
# reductions and must also agree with a single full-batch call.
P = 2
keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(1, B + 1))
xis = jax.vmap(lambda k: 0.1 * jax.random.normal(k, (3, T)))(keys)
V = jnp.asarray(np.stack(inputs))

def experiments(xi):
    return jax.vmap(model.simulate_trajectory, (0, 0, None))(V, xi, 0.0)

def estimate(xi):
    y = experiments(xi)
    r = estimate_giri(design, y[0], y[1], y[2])
    return hbjax.flatten_params(r.model), r.offset, r.cond_ls, r.result

def refined(xi):
    # The closed form, then prediction-error refinement (the Monte Carlo 'refined' estimator).
    y = experiments(xi)
    start = estimate_giri(design, y[0], y[1], y[2]).model
    res = refine_traceable(start, tuple((V[k], y[k]) for k in range(3)), h_m=design.h_m,
                           max_steps=16)
    return hbjax.flatten_params(res.model), res.result._value

def chunked(run, size):
    outs = [run(xis[i:i + size]) for i in range(0, B, size)]
    return jax.tree_util.tree_map(lambda *x: np.concatenate([np.asarray(l) for l in x]), *outs)

n = jax.device_count()
assert B % (n * P) == 0
sharding = NamedSharding(Mesh(np.array(jax.devices()), ("batch",)), PartitionSpec("batch"))
for name, f in (("simulate", experiments), ("estimate_giri", estimate), ("refine", refined)):
    if name != "refine":  # refinement compiles slowly: its sharded run is compared across processes
        digest(f"vmap_{name}", chunked(jax.jit(jax.vmap(f)), P))
        # (not refine under pmap: lineax's operator-structure check fails on shard_map avals)
        pmapped = jax.pmap(jax.vmap(f))
        digest(f"pmap_{name}", chunked(
            lambda x: jax.tree_util.tree_map(lambda l: l.reshape((n * P,) + l.shape[2:]),
                                             pmapped(x.reshape((n, P) + x.shape[1:]))), n * P))
    sharded = jax.jit(jax.vmap(f), out_shardings=sharding)
    digest(f"sharded_{name}", chunked(lambda x: sharded(jax.device_put(x, sharding)), n * P))
digest("vmap_simulate_full_batch", jax.jit(jax.vmap(experiments))(xis))
print(json.dumps({"devices": n, "digests": digests}))
'''


def run_job(devices: int) -> dict:
    env = dict(os.environ)
    flags = env.get("XLA_FLAGS", "")
    env["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={devices}".strip()
    env["JAX_PLATFORMS"] = "cpu"
    env["JAX_ENABLE_X64"] = "1"  # the estimators need float64; hbjax leaves the switch to us
    out = subprocess.run([sys.executable, "-c", JOB], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["devices"] == devices
    return result["digests"]


@pytest.fixture(scope="module")
def one_device():
    return run_job(1)


@pytest.fixture(scope="module")
def four_devices():
    return run_job(4)


def test_batched_and_sharded_results_equal_the_unbatched_ones(four_devices):
    d = four_devices
    assert d["pmap_simulate"] == d["vmap_simulate"] == d["sharded_simulate"]
    assert d["vmap_simulate"] == d["vmap_simulate_full_batch"]
    assert d["pmap_estimate_giri"] == d["vmap_estimate_giri"] == d["sharded_estimate_giri"]


def test_same_key_same_bits_across_processes_and_device_counts(one_device, four_devices):
    # Two processes (so also two runs), sharded over 1 and over 4 devices.
    assert set(one_device) == set(four_devices)
    assert four_devices == one_device


def test_same_key_same_bits_within_a_process():
    import jax

    import hbjax

    model, design = hbjax.default_system(), hbjax.default_design()
    v = design.staircase_input(500)

    def once():
        xi = 0.1 * jax.random.normal(jax.random.key(3), (500,))
        return np.asarray(hbjax.simulate(model, v, xi))

    first, second = once(), once()
    assert first.tobytes() == second.tobytes()
    other = 0.1 * jax.random.normal(jax.random.key(4), (500,))
    assert np.asarray(hbjax.simulate(model, v, other)).tobytes() != first.tobytes()


def test_diagnose_gives_the_same_report_twice():
    # The diagnosis runs batched fits and residual tests; two runs must agree exactly.
    import json

    import hbjax

    rec = hbjax.concealed_recording("output_saturation", n=600, key=jax_key(7))
    effects = ["output_saturation", "extra_delay"]
    first = hbjax.diagnose(rec.model, rec.v, rec.y, effects=effects)
    second = hbjax.diagnose(rec.model, rec.v, rec.y, effects=effects)
    assert json.dumps(first.to_dict(), sort_keys=True) == json.dumps(second.to_dict(), sort_keys=True)
    assert first.mismatch and first.findings


def jax_key(seed):
    import jax

    return jax.random.key(seed)
