"""The compiled chunk of a Monte Carlo study: on each device of a 1-D mesh, a loop over
groups of keys, each group a ``vmap`` of one realisation (simulate the three experiments,
estimate) of a width fixed by the record length, so every realisation gets the same bits
whatever the layout; executables of the built-in estimators are kept between studies.
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


# Default group: realisation-samples per device (realisations x record length). On CPU a
# batch whose records stay in cache runs 2-3x faster than one streaming through memory
# (measured: 26 realisations of 10 000 samples beat 419), and memory stays far below 2 GB.
#
# Every realisation is computed by one `vmap` of a fixed width, the *group*, a function of
# the record length (and `chunk_size`) only, never of the number of realisations or devices:
# XLA compiles a vmapped estimator to different reduction orders for different batch sizes
# (the sums over time differed by up to 7e-15 at N = 1200 between batches of 96 and 130), so
# a fixed group, a padded last chunk and keys ``fold_in(key, r)`` make every realisation's
# estimate the same bits whatever the layout. A chunk holds eight groups per device on CPU
# and runs only the groups that hold requested realisations (a loop with a runtime trip
# count in one executable), so a study pads less than one group per length, not up to a
# chunk. The records are simulated group by group inside the loop, so the cache argument
# above is the group's; the chunk only sets how many dispatches a study takes (measured,
# 200 realisations at N = 1000 and 4000: 84-89 ms with two groups per chunk, 79-84 ms with
# eight).
#
# CPU group: 16 to 32 realisations. Measured per realisation of the closed form inside one
# compiled chunk (2-core Xeon): N = 1000: 83 us in a vmap of 64, 91 us of 32, 109 us of 16,
# 151 us of 8; N = 4000: 278, 254, 314, 416 us. Long records keep at least 16 per group so
# the time loop is amortised.
#
# An accelerator is the opposite case: each step of the time loop is a kernel launch whatever
# the batch, so a group must hold many realisations to fill the device (measured on an H200
# at N = 10 000: 708 realisations/s with the CPU's 26 per chunk, 18 189 with 1000). Its
# default is one group of 2**23 realisation-samples (192 MiB of float64 records for the
# three experiments), at most 1024 realisations.
_GROUP_SAMPLES = {"cpu": 2**18, "accelerator": 2**23}
_MIN_GROUP = 16
_MAX_GROUP = {"cpu": 32, "accelerator": 1024}
_GROUPS_PER_CHUNK = {"cpu": 8, "accelerator": 1}
AXIS = "realisations"


def chunk_layout(length, chunk_size, platform="cpu"):
    """``(group, per_device)``: realisations per vmapped group and per device per chunk, from
    `length`, `chunk_size` and the devices' kind (`platform`, ``"cpu"`` or an accelerator's)
    only, see above. A given `chunk_size` is one group of that size. At least 2: XLA
    compiles a batch of one to different code (it drops the unit axis)."""
    if chunk_size is not None:
        return max(2, chunk_size), max(2, chunk_size)
    kind = "cpu" if platform == "cpu" else "accelerator"
    group = min(_MAX_GROUP[kind], max(_MIN_GROUP, _GROUP_SAMPLES[kind] // length))
    return group, group * _GROUPS_PER_CHUNK[kind]


def active_groups(realisations, chunk, per_device, group, n_dev):
    """The groups of chunk `chunk` to run: enough for the first device's keys below
    `realisations` (the first device holds the most), the loop's trip count."""
    active = min(max(realisations - chunk * per_device * n_dev, 0), per_device)
    return np.int32(-(-active // group))


def chunk_fn(design, length, noise, draw, estimator, impl):
    """``(model, noise_std, key_data) -> (theta (B, P), code (B,))`` for one group of
    realisations of the three experiments. The model and noise level are arguments so that
    one compiled chunk serves every study with the same structure (see
    `chunk_executable`)."""
    v = jnp.asarray(np.stack([design.constant_input(length), design.binary_input(length),
                              design.staircase_input(length)]))

    def records(model, noise_std, key):
        simulate = jax.vmap(model.simulate_trajectory, in_axes=(0, 0, None))
        e = noise_std * jax.vmap(draw)(jax.random.split(key, 3))
        if noise == "output":
            # The noise-free part does not depend on the key, so vmap computes it once.
            return simulate(v, jnp.zeros_like(v), 0.0) + e
        return simulate(v, e, 0.0)

    def estimate(model, y):
        res = estimator(design, y[0], y[1], y[2])
        if not (hasattr(res, "model") and hasattr(res, "result")):
            raise TypeError(
                "`estimator` must return an object with `.model` (an hbjax.Hammerstein) and "
                f"`.result` (an integer result code), got {type(res).__name__}."
            )
        if not isinstance(res.model, Hammerstein):
            raise TypeError(
                "`estimator` must return an object whose `.model` is an hbjax.Hammerstein, "
                f"got {type(res.model).__name__}."
            )
        got = (res.model.arx.na, res.model.arx.nb, res.model.backlash.m)
        want = (model.arx.na, model.arx.nb, model.backlash.m)
        if got != want:
            raise ValueError(
                "`estimator` must return a model of the studied system's orders (na, nb, m) "
                f"= {want}, got {got}.")
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
            return jax.lax.map(lambda y_: estimate(model, y_), y)
        return jax.vmap(lambda y_: estimate(model, y_))(y)

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


def _looped(group_fn, group, per_device, sharding):
    """``(model, noise_std, key_data (n_dev * per_device, ...), groups) -> (theta, code)``: a
    loop over the first ``groups`` groups of every device's keys, each step one `group_fn`
    over `group` keys per device (sharded like the keys, so each device computes a vmap of
    `group`); the rest of the outputs stay zero (padding the caller drops)."""
    n_dev = sharding.mesh.size
    n_groups = per_device // group

    def chunk(model, noise_std, key_data, groups):
        keys = key_data.reshape((n_dev, n_groups, group) + key_data.shape[1:])
        shapes = jax.eval_shape(group_fn, model, noise_std, keys[:, 0].reshape(
            (n_dev * group,) + key_data.shape[1:]))
        out = tuple(jnp.zeros((n_groups,) + s.shape, s.dtype) for s in shapes)

        def body(i, out):
            step_keys = jax.lax.with_sharding_constraint(
                keys[:, i].reshape((n_dev * group,) + key_data.shape[1:]), sharding)
            return tuple(o.at[i].set(r) for o, r in zip(out, group_fn(model, noise_std, step_keys)))

        out = jax.lax.fori_loop(0, groups, body, out)
        # (group index, device, realisation in group) -> the keys' order (device first).
        return tuple(
            jnp.swapaxes(o.reshape((n_groups, n_dev, group) + o.shape[2:]), 0, 1)
            .reshape((n_dev * per_device,) + o.shape[2:]) for o in out)

    return chunk


def chunk_executable(model, design, length, noise, draw, estimator, group, per_device,
                     sharding, key):
    """The jitted, sharded chunk: per device, a loop over groups of `group` realisations (one
    ``vmap`` each) of `per_device` keys; and the seconds its compilation took (0 when
    reused). Called as ``(model, noise_std, key_data, groups)`` with ``groups`` from
    `active_groups`."""
    cache_key, hit = None, None
    if isinstance(noise, str) and estimator in (giri, refined):
        leaves, treedef = jax.tree_util.tree_flatten(model)
        cache_key = (treedef, tuple((jnp.shape(x), jnp.result_type(x)) for x in leaves),
                     design, length, noise, estimator, group, per_device, sharding, key.dtype)
        try:
            hit = _EXECUTABLES.get(cache_key)
        except TypeError:  # an unhashable model extension: compile every time
            cache_key = None
    if hit is not None:
        return hit, 0.0
    group_fn = chunk_fn(design, length, noise, draw, estimator, jax.random.key_impl(key))
    chunk = _looped(group_fn, group, per_device, sharding)
    replicated = NamedSharding(sharding.mesh, PartitionSpec())
    batched = jax.jit(chunk,
                      in_shardings=(replicated, replicated, sharding, replicated),
                      out_shardings=(sharding, sharding))
    t0 = time.perf_counter()
    data = jax.random.key_data(key)
    n_dev = sharding.mesh.size
    key_spec = jax.ShapeDtypeStruct((per_device * n_dev,) + data.shape, data.dtype,
                                    sharding=sharding)
    groups_spec = jax.ShapeDtypeStruct((), jnp.int32, sharding=replicated)
    compiled = batched.lower(model, jnp.float64(0.0), key_spec, groups_spec).compile()
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
