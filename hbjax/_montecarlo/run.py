"""Monte Carlo consistency studies: simulate the paper's three experiments (eqs. (14),
(27), (32)) under many independent noise draws and re-estimate every time.

Simulation and estimation of one realisation are written for one trajectory and
``jax.vmap``-ed over a chunk of realisations (compiled once per record length), the chunk
is sharded over a 1-D device mesh, and chunks run one after another so memory stays
bounded whatever the number of realisations.
"""

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._core.cache import ensure_compilation_cache
from .._core.mappings import release_compiled_programs
from .._core.model import Hammerstein
from .._core.params import flatten_params, param_names
from .._core.precision import require_x64
from .._core.progress import check_progress, make_bar
from .._core.signals import GiriDesign
from .._identify.giri import normalise
from .._misc import check_bool, positive_float, positive_int
from .checks import (
    check_lengths,
    check_study_key,
    noise_draw,
    resolve_devices,
    resolve_estimator,
)
from .chunks import AXIS, active_groups, chunk_executable, chunk_layout, global_array, to_host
from .study import Study


def _progress(total, enabled):
    """A tqdm bar over chunks (the policy of ``_core/progress.py``: after 2 s, on a
    terminal or in Jupyter, never with ``progress=False``)."""
    return make_bar(enabled, total=total, desc="monte carlo", unit="chunk", live=True)


def monte_carlo(
    model: Hammerstein,
    design: GiriDesign,
    *,
    noise_std,
    lengths,
    realisations,
    key,
    estimator="giri",
    noise="equation",
    chunk_size=None,
    progress=True,
    devices=None,
    keep_estimates=False,
) -> Study:
    """Monte Carlo study of an estimator on the paper's three experiments.

    For every record length ``N`` in `lengths` and every realisation ``r``, the three
    experiments ``v1`` (eq. (14)), ``v2`` (eq. (27)) and ``v3`` (eq. (32)) of ``N`` samples
    each are simulated with independent noise (key ``fold_in(fold_in(key, N), r)``, split in
    three), the estimator is applied, and the normalised estimate is compared with
    ``normalise(model, design.h_m)``. Propositions 1-2 predict RMSE ``~ N^-1/2`` under
    assumption A6 (white equation error); :class:`Study` reports the fitted slope.

    **Arguments:**

    - `model`: the true :class:`hbjax.Hammerstein`; `design`: its :class:`hbjax.GiriDesign`.
    - `noise_std`: standard deviation of the noise (scale of the callable's record).
    - `lengths`: record lengths per experiment, each at least one period of ``v3``.
    - `realisations`: independent noise draws per length.
    - `key`: a JAX PRNG key (``jax.random.key(0)``).
    - `estimator`: ``"giri"`` (closed form, :func:`hbjax.identify_giri`'s traceable core),
      ``"refined"`` (closed form then prediction-error refinement) or a callable
      ``(design, y1, y2, y3) -> result`` with ``.model`` (normalised Hammerstein) and
      ``.result`` (integer code, 0 = success; a float code is refused, one beyond int32
      is clipped, never wrapped to 0); it must be traceable (jit/vmap) and not raise. A
      callable `estimator` or `noise` is traced afresh on every call, so it may read state
      that changes between studies.
    - `noise`: ``"equation"`` (white ``xi`` of eq. (10)), ``"output"`` (white noise added to
      ``y``) or a callable ``(key, length) -> record (length,)`` used as the equation error
      ``xi`` (times `noise_std`), e.g. AR(1) coloured noise.
    - `chunk_size`: realisations per device per chunk, the memory bound, computed as one
      ``vmap`` (at least 2; the last chunk is padded). Default: on CPU eight groups of
      ``min(32, max(16, 2**18 // N))`` realisations, records that stay in cache, and only
      the groups that hold requested realisations run; on an accelerator one group of
      ``min(1024, max(16, 2**23 // N))``, enough to fill it. Neither `realisations` nor the
      number of devices changes the groups, so neither changes any realisation's
      estimate; a different `chunk_size` may change the last bits (XLA's reduction order
      depends on the batch).
    - `progress`: tqdm bar over chunks once the study has run for more than 2 s, on a
      terminal or in a notebook; ``False`` silences it, a dict passes options to tqdm.
    - `devices`: devices to shard realisations over (default: all, ``jax.devices()``).
      Results are bitwise identical for any number of devices, and realisation ``r``'s
      estimate is the same bits in a study of any size.
    - `keep_estimates`: keep the raw estimates in ``Study.estimates``.

    **Returns:** a :class:`hbjax.Study`. Failed realisations (non-zero result code) are
    excluded from the statistics and counted; they never abort the study.
    """
    require_x64("monte_carlo")
    ensure_compilation_cache()
    release_compiled_programs()
    check_progress(progress)
    keep_estimates = check_bool(keep_estimates, "keep_estimates")
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    if not isinstance(design, GiriDesign):
        raise TypeError(f"`design` must be an hbjax.GiriDesign, got {type(design).__name__}.")
    # Orders that match the design, and the true system inside the method's assumptions
    # (A3, A4, A5, a band over the excited range): otherwise every realisation would fail.
    design.check_model(model, assumptions=True)
    noise_std = positive_float(noise_std, "noise_std", allow_zero=True)
    lengths = check_lengths(lengths, design)
    realisations = positive_int(realisations, "realisations")
    key = check_study_key(key)
    if chunk_size is not None:
        chunk_size = positive_int(chunk_size, "chunk_size")
    estimator_fn, estimator_name = resolve_estimator(estimator)
    devices = resolve_devices(devices)
    draws = {n: noise_draw(noise, n) for n in lengths}  # validates a callable up front
    noise_name = noise if isinstance(noise, str) else getattr(noise, "__name__", "callable")
    true = np.asarray(flatten_params(normalise(model, design.h_m)))

    n_dev = len(devices)
    sharding = NamedSharding(Mesh(np.array(devices), (AXIS,)), PartitionSpec(AXIS))
    layout = {n: chunk_layout(n, chunk_size, devices[0].platform) for n in lengths}
    n_chunks = {n: -(-realisations // (layout[n][1] * n_dev)) for n in lengths}
    replicated = NamedSharding(sharding.mesh, PartitionSpec())
    model_r = jax.tree_util.tree_map(lambda x: global_array(np.asarray(x), replicated), model)
    std_r = global_array(np.asarray(noise_std, np.float64), replicated)
    bar = _progress(sum(n_chunks.values()), progress)
    estimates = np.empty((len(lengths), realisations, true.size))
    codes = np.empty((len(lengths), realisations), np.int32)
    compile_s, run_s = np.zeros(len(lengths)), np.zeros(len(lengths))
    try:
        for i, n in enumerate(lengths):
            group, per_device = layout[n]
            step = per_device * n_dev
            compiled, compile_s[i] = chunk_executable(
                model, design, n, noise, draws[n], estimator_fn, group, per_device, sharding,
                key)
            t0 = time.perf_counter()
            # Keys depend on (N, r) only: adding realisations or devices keeps old draws.
            # All of a length's keys in one call (an eager vmap per chunk cost milliseconds).
            all_keys = np.asarray(_realisation_keys(key, n, n_chunks[n] * step))
            pending = []
            for c in range(n_chunks[n]):
                idx = np.arange(c * step, (c + 1) * step)
                keys = global_array(all_keys[c * step:(c + 1) * step], sharding)
                groups = global_array(
                    active_groups(realisations, c, per_device, group, n_dev), replicated)
                # Dispatch is asynchronous: the next chunk is queued while this one runs.
                pending.append((idx, compiled(model_r, std_r, keys, groups)))
                if len(pending) > 1:
                    _collect(pending.pop(0), estimates[i], codes[i], realisations, bar)
            while pending:
                _collect(pending.pop(0), estimates[i], codes[i], realisations, bar)
            run_s[i] = time.perf_counter() - t0
    finally:
        if bar is not None:
            bar.close()
    return Study.from_estimates(
        lengths, param_names(model), true, estimates, codes, keep_estimates=keep_estimates,
        compile_seconds=compile_s, run_seconds=run_s, realisations=realisations,
        noise_std=noise_std, estimator=estimator_name, noise=noise_name, n_devices=n_dev,
        chunk_size=int(min(layout[n][1] for n in lengths)),
    )


@functools.partial(jax.jit, static_argnums=(1, 2))
def _realisation_keys(key, length: int, count: int):
    """The key data of realisations ``0 .. count - 1`` at record length ``length``:
    ``fold_in(fold_in(key, length), r)``."""
    key_n = jax.random.fold_in(key, length)
    keys = jax.vmap(jax.random.fold_in, (None, 0))(key_n, jnp.arange(count))
    return jax.random.key_data(keys)


def _collect(item, estimates, codes, realisations, bar):
    idx, (theta, code) = item
    keep = idx < realisations  # the last chunk is padded to keep one compiled shape
    estimates[idx[keep]] = to_host(theta)[keep]
    codes[idx[keep]] = to_host(code)[keep]
    if bar is not None:
        bar.update(1)
