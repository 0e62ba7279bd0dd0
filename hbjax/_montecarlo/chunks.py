"""The compiled chunk of a Monte Carlo study: a ``vmap`` of one realisation (simulate the
three experiments, estimate) over a chunk of keys, sharded over a 1-D device mesh, with the
per-device batch fixed by the record length so every realisation gets the same bits whatever
the layout; executables of the built-in estimators are kept between studies.
"""

import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from .._core.model import Hammerstein
from .._core.params import flatten_params
from .._identify.giri import NONFINITE
from .checks import giri, refined, result_code


# Default chunk: realisation-samples per device (realisations x record length). On CPU a
# chunk whose records stay in cache runs 2-3x faster than one streaming through memory
# (measured: 26 realisations of 10 000 samples beat 419), and memory stays far below 2 GB;
# long records keep at least 16 realisations per chunk so the time loop is amortised, and
# short ones at most 64, so that a small study pads little.
#
# The per-device batch is a function of the record length (and `chunk_size`) only, never of
# the number of realisations or devices: XLA compiles a vmapped estimator to different
# reduction orders for different batch sizes (the sums over time differed by up to 7e-15 at
# N = 1200 between batches of 96 and 130), so a fixed batch, a padded last chunk and keys
# ``fold_in(key, r)`` make every realisation's estimate the same bits whatever the layout.
#
# An accelerator is the opposite case: each step of the time loop is a kernel launch whatever
# the batch, so a chunk must hold many realisations to fill the device (measured on an H200
# at N = 10 000: 708 realisations/s with the CPU's 26 per chunk, 18 189 with 1000). Its
# default is 2**23 realisation-samples (192 MiB of float64 records for the three
# experiments), at most 1024 realisations.
_CHUNK_SAMPLES = {"cpu": 2**18, "accelerator": 2**23}
_MIN_CHUNK = 16
_MAX_CHUNK = {"cpu": 64, "accelerator": 1024}
AXIS = "realisations"


def batch_per_device(length, chunk_size, platform="cpu"):
    """Realisations per device per chunk: from `length`, `chunk_size` and the devices' kind
    (`platform`, ``"cpu"`` or an accelerator's) only, see above. At least 2: XLA compiles a
    batch of one to different code (it drops the unit axis)."""
    if chunk_size is not None:
        return max(2, chunk_size)
    kind = "cpu" if platform == "cpu" else "accelerator"
    return min(_MAX_CHUNK[kind], max(_MIN_CHUNK, _CHUNK_SAMPLES[kind] // length))


def chunk_fn(design, length, noise, draw, estimator, impl):
    """``(model, noise_std, key_data) -> (theta (B, P), code (B,))`` for a chunk of realisations
    of the three experiments. The model and noise level are arguments so that one compiled
    chunk serves every study with the same structure (see `chunk_executable`)."""
    v = jnp.asarray(np.stack([design.constant_input(length), design.binary_input(length),
                              design.staircase_input(length)]))

    def records(model, noise_std, key):
        simulate = jax.vmap(model.simulate_trajectory, in_axes=(0, 0, None))
        e = noise_std * jax.vmap(draw)(jax.random.split(key, 3))
        if noise == "output":
            # The noise-free part does not depend on the key, so vmap computes it once.
            return simulate(v, jnp.zeros_like(v), 0.0) + e
        return simulate(v, e, 0.0)

    def estimate(y):
        res = estimator(design, y[0], y[1], y[2])
        if not isinstance(res.model, Hammerstein):
            raise TypeError(
                "`estimator` must return an object whose `.model` is an hbjax.Hammerstein, "
                f"got {type(res.model).__name__}."
            )
        theta = flatten_params(res.model)
        code = result_code(res.result)
        code = jnp.where((code == 0) & ~jnp.all(jnp.isfinite(theta)), NONFINITE, code)
        return theta, code

    def chunk(model, noise_std, key_data):
        keys = jax.random.wrap_key_data(key_data, impl=impl)
        # Two vmaps rather than one: the simulation scans over time-major arrays (one
        # realisation per lane), and out_axes=0 hands the estimator realisation-major
        # records, whose reductions over time run about twice as fast on CPU.
        y = jax.vmap(records, in_axes=(None, None, 0), out_axes=0)(model, noise_std, keys)
        if estimator is refined:
            # An iterative solve per realisation: sequential `lax.map` keeps each fit's
            # (T, p) Jacobian in cache and stops each at its own convergence, several times
            # faster on CPU than a vmapped solve that runs every lane for the slowest one.
            return jax.lax.map(estimate, y)
        return jax.vmap(estimate)(y)

    return chunk


# Compiled chunk executables of the built-in estimators and noises, keyed by everything
# that shapes the program (not the values of the model parameters or the noise level):
# repeated studies do not recompile. A user's callable is traced again on every call: what
# it computes may depend on state that neither equality nor identity sees (the object
# behind a bound method, a global it reads), and a cached program would silently reuse
# the first study's. (JAX's persistent compilation cache still skips XLA's compilation
# when the traced program is unchanged.)
_EXECUTABLES: dict = {}
_MAX_EXECUTABLES = 16


def chunk_executable(model, design, length, noise, draw, estimator, step, sharding, key):
    """The jitted, sharded ``vmap`` of one realisation over a chunk of ``step`` keys, and
    the seconds its compilation took (0 when reused)."""
    cache_key, hit = None, None
    if isinstance(noise, str) and estimator in (giri, refined):
        leaves, treedef = jax.tree_util.tree_flatten(model)
        cache_key = (treedef, tuple((jnp.shape(x), jnp.result_type(x)) for x in leaves),
                     design, length, noise, estimator, step, sharding, key.dtype)
        try:
            hit = _EXECUTABLES.get(cache_key)
        except TypeError:  # an unhashable model extension: compile every time
            cache_key = None
    if hit is not None:
        return hit, 0.0
    chunk = chunk_fn(design, length, noise, draw, estimator, jax.random.key_impl(key))
    replicated = NamedSharding(sharding.mesh, PartitionSpec())
    batched = jax.jit(chunk,
                      in_shardings=(replicated, replicated, sharding),
                      out_shardings=(sharding, sharding))
    t0 = time.perf_counter()
    data = jax.random.key_data(key)
    key_spec = jax.ShapeDtypeStruct((step,) + data.shape, data.dtype, sharding=sharding)
    compiled = batched.lower(model, jnp.float64(0.0), key_spec).compile()
    seconds = time.perf_counter() - t0
    if cache_key is not None:
        if len(_EXECUTABLES) >= _MAX_EXECUTABLES:
            _EXECUTABLES.pop(next(iter(_EXECUTABLES)))
        _EXECUTABLES[cache_key] = compiled
    return compiled, seconds


def global_array(host, sharding):
    """A (possibly multi-process) array from a host array every process holds identically:
    each process fills only its own devices' shards (works with jax.distributed)."""
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def to_host(x):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)
