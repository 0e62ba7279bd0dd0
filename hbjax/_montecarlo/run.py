"""Monte Carlo consistency studies: simulate the paper's three experiments (eqs. (14),
(27), (32)) under many independent noise draws and re-estimate every time.

Simulation and estimation of one realisation are written for one trajectory and
``jax.vmap``-ed over a chunk of realisations (compiled once per record length), the chunk
is sharded over a 1-D device mesh, and chunks run one after another so memory stays
bounded whatever the number of realisations.
"""

import inspect
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._misc import check_key, positive_float, positive_int
from .._core.cache import ensure_compilation_cache
from .._core.precision import require_x64
from .._core.progress import check_progress, make_bar
from .._identify.giri import NONFINITE, estimate_giri, normalise
from .._core.model import Hammerstein
from .._core.params import flatten_params, param_names
from .._core.signals import GiriDesign
from .._results import RESULTS
from .study import Study


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
_CHUNK_SAMPLES = 2**18
_MIN_CHUNK = 16
_MAX_CHUNK = 64
_AXIS = "realisations"


def _check_key(key):
    key = check_key(key)
    if key.dtype == jnp.uint32:  # legacy jax.random.PRNGKey
        return jax.random.wrap_key_data(key)
    return key


def _check_lengths(lengths, design):
    if isinstance(lengths, (int, np.integer)) and not isinstance(lengths, bool):
        lengths = [lengths]
    if isinstance(lengths, (str, bytes)) or not isinstance(lengths, (Sequence, np.ndarray)):
        raise TypeError(f"`lengths` must be a sequence of integers, got {type(lengths).__name__}.")
    out = [positive_int(n, "lengths") for n in np.asarray(lengths, dtype=object).ravel()]
    if not out:
        raise ValueError("`lengths` must hold at least one record length.")
    minimum = max(design.staircase_period, design.binary_period)
    short = [n for n in out if n < minimum]
    if short:
        raise ValueError(
            f"`lengths` {short} are shorter than one period of v3 (2m(n+1) = "
            f"{design.staircase_period} samples for this design; v2's period is "
            f"{design.binary_period}): every record must cover at least {minimum} samples."
        )
    if len(set(out)) != len(out):
        raise ValueError(f"`lengths` must be distinct, got {out}.")
    return out


def _noise_draw(noise, length):
    """``key -> unit-scale record (T,)`` for the white cases or the user's callable."""
    if noise in ("equation", "output"):
        return lambda k: jax.random.normal(k, (length,), jnp.float32).astype(jnp.float64)
    if not callable(noise):
        raise ValueError(
            f"`noise` must be 'equation', 'output' or a callable (key, length) -> record, "
            f"got {noise!r}."
        )
    try:
        n_args = len(inspect.signature(noise).parameters)
    except (TypeError, ValueError):
        n_args = 2
    draw = (lambda k: noise(k, length)) if n_args >= 2 else noise
    try:
        out = jax.eval_shape(draw, jax.random.key(0))
    except Exception as err:  # the user's code: say where it failed
        raise ValueError(f"calling the `noise` callable with (key, {length}) failed: {err}") from err
    if not hasattr(out, "shape") or out.shape != (length,) or not jnp.issubdtype(out.dtype, jnp.floating):
        got = f"shape {tuple(out.shape)} and dtype {out.dtype}" if hasattr(out, "shape") else repr(out)
        raise ValueError(
            f"the `noise` callable must return a float record of shape ({length},) for a "
            f"record length of {length}, got {got}."
        )
    return lambda k: draw(k).astype(jnp.float64)


def _giri(design, y1, y2, y3):
    return estimate_giri(design, y1, y2, y3)


def _refined(design, y1, y2, y3):
    """Closed form (the initial model), then prediction-error refinement on the three
    experiments. A failed closed form keeps its own result; otherwise the refinement's
    (one enumeration, :class:`hbjax.RESULTS`, for both)."""
    from .._identify.refine import refine_traceable

    first = estimate_giri(design, y1, y2, y3)
    length = y1.shape[0]
    inputs = (design.constant_input(length), design.binary_input(length),
              design.staircase_input(length))
    recordings = tuple((jnp.asarray(v), y) for v, y in zip(inputs, (y1, y2, y3)))
    res = refine_traceable(first.model, recordings, criterion="prediction", h_m=design.h_m,
                           max_steps=64)
    result = RESULTS.where(first.result != RESULTS.successful, first.result, res.result)
    return _Outcome(res.model, result)


def _per_device(length, chunk_size):
    """Realisations per device per chunk: from `length` and `chunk_size` only (see above).
    At least 2: XLA compiles a batch of one to different code (it drops the unit axis)."""
    if chunk_size is not None:
        return max(2, chunk_size)
    return min(_MAX_CHUNK, max(_MIN_CHUNK, _CHUNK_SAMPLES // length))


def _result_code(result):
    """The int32 result code of one realisation from an estimator's ``.result``: an integer
    (or boolean) scalar, 0 = success. Refused at trace time when it is not an integer; a
    value outside the int32 range is clipped to its ends, so that a non-zero code never
    wraps to 0 (success)."""
    raw = getattr(result, "_value", result)
    try:
        raw = jnp.asarray(raw)
    except (TypeError, ValueError, OverflowError) as err:
        raise TypeError(
            "the `estimator`'s `.result` must be an integer result code (0 = success), got "
            f"{type(raw).__name__}: {err}"
        ) from None
    if not (jnp.issubdtype(raw.dtype, jnp.integer) or raw.dtype == jnp.bool_):
        raise TypeError(
            "the `estimator`'s `.result` must be an integer result code (0 = success), got "
            f"dtype {raw.dtype}; a float code such as 0.7 would be truncated to 0 (success)."
        )
    if raw.size != 1:
        raise ValueError(
            "the `estimator`'s `.result` must be one result code per realisation, got shape "
            f"{tuple(raw.shape)}."
        )
    raw = raw.reshape(())
    if raw.dtype == jnp.bool_:
        return raw.astype(jnp.int32)
    have, want = jnp.iinfo(raw.dtype), jnp.iinfo(jnp.int32)
    if have.min < want.min or have.max > want.max:
        raw = jnp.clip(raw, max(have.min, want.min), min(have.max, want.max))
    return raw.astype(jnp.int32)


def _resolve_estimator(estimator):
    if estimator == "giri":
        return _giri, "giri"
    if estimator == "refined":
        try:
            from .._identify.refine import refine_traceable  # noqa: F401
        except ImportError:
            raise NotImplementedError(
                "estimator='refined' needs hbjax._identify.refine.refine_traceable (prediction-error "
                "refinement, issue 3), which this installation does not have; use "
                "estimator='giri' or pass your own callable (design, y1, y2, y3) -> result "
                "with `.model` and `.result`."
            ) from None

        return _refined, "refined"
    if callable(estimator):
        return estimator, getattr(estimator, "__name__", type(estimator).__name__)
    raise ValueError(
        f"`estimator` must be 'giri', 'refined' or a callable (design, y1, y2, y3) -> result "
        f"with `.model` and `.result`, got {estimator!r}."
    )


class _Outcome:
    def __init__(self, model, result):
        self.model, self.result = model, result


def _chunk_fn(design, length, noise, draw, estimator, impl):
    """``(model, noise_std, key_data) -> (theta (B, P), code (B,))`` for a chunk of realisations
    of the three experiments. The model and noise level are arguments so that one compiled
    chunk serves every study with the same structure (see `_chunk_executable`)."""
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
        code = _result_code(res.result)
        code = jnp.where((code == 0) & ~jnp.all(jnp.isfinite(theta)), NONFINITE, code)
        return theta, code

    def chunk(model, noise_std, key_data):
        keys = jax.random.wrap_key_data(key_data, impl=impl)
        # Two vmaps rather than one: the simulation scans over time-major arrays (one
        # realisation per lane), and out_axes=0 hands the estimator realisation-major
        # records, whose reductions over time run about twice as fast on CPU.
        y = jax.vmap(records, in_axes=(None, None, 0), out_axes=0)(model, noise_std, keys)
        if estimator is _refined:
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


def _chunk_executable(model, design, length, noise, draw, estimator, step, sharding, key):
    """The jitted, sharded ``vmap`` of one realisation over a chunk of ``step`` keys, and
    the seconds its compilation took (0 when reused)."""
    cache_key, hit = None, None
    if isinstance(noise, str) and estimator in (_giri, _refined):
        leaves, treedef = jax.tree_util.tree_flatten(model)
        cache_key = (treedef, tuple((jnp.shape(x), jnp.result_type(x)) for x in leaves),
                     design, length, noise, estimator, step, sharding, key.dtype)
        try:
            hit = _EXECUTABLES.get(cache_key)
        except TypeError:  # an unhashable model extension: compile every time
            cache_key = None
    if hit is not None:
        return hit, 0.0
    chunk = _chunk_fn(design, length, noise, draw, estimator, jax.random.key_impl(key))
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


def _resolve_devices(devices):
    if devices is None:
        return list(jax.devices())
    if isinstance(devices, jax.Device):
        return [devices]
    devices = list(devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise TypeError("`devices` must be None or a non-empty sequence of jax.Device.")
    return devices


def _progress(total, enabled):
    """A tqdm bar over chunks (the policy of ``_core/progress.py``: after 2 s, on a
    terminal or in Jupyter, never with ``progress=False``)."""
    return make_bar(enabled, total=total, desc="monte carlo", unit="chunk", live=True)


def _global_array(host, sharding):
    """A (possibly multi-process) array from a host array every process holds identically:
    each process fills only its own devices' shards (works with jax.distributed)."""
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def _to_host(x):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


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
    - `chunk_size`: realisations per device per chunk (default
      ``min(64, max(16, 2**18 // N))``), the memory bound; a chunk runs
      ``chunk_size * n_devices`` realisations at once (at least 2 per device; the last
      chunk is padded). The chunk does not depend on `realisations` or on the devices, so
      neither changes any realisation's estimate; a different `chunk_size` may change the
      last bits (XLA's reduction order depends on the batch).
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
    check_progress(progress)
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    if not isinstance(design, GiriDesign):
        raise TypeError(f"`design` must be an hbjax.GiriDesign, got {type(design).__name__}.")
    # Orders that match the design, and the true system inside the method's assumptions
    # (A3, A4, A5, a band over the excited range): otherwise every realisation would fail.
    design.check_model(model, assumptions=True)
    noise_std = positive_float(noise_std, "noise_std", allow_zero=True)
    lengths = _check_lengths(lengths, design)
    realisations = positive_int(realisations, "realisations")
    key = _check_key(key)
    if chunk_size is not None:
        chunk_size = positive_int(chunk_size, "chunk_size")
    estimator_fn, estimator_name = _resolve_estimator(estimator)
    devices = _resolve_devices(devices)
    draws = {n: _noise_draw(noise, n) for n in lengths}  # validates a callable up front
    noise_name = noise if isinstance(noise, str) else getattr(noise, "__name__", "callable")
    true = np.asarray(flatten_params(normalise(model, design.h_m)))

    n_dev = len(devices)
    sharding = NamedSharding(Mesh(np.array(devices), (_AXIS,)), PartitionSpec(_AXIS))
    per_device = {n: _per_device(n, chunk_size) for n in lengths}
    n_chunks = {n: -(-realisations // (per_device[n] * n_dev)) for n in lengths}
    replicated = NamedSharding(sharding.mesh, PartitionSpec())
    model_r = jax.tree_util.tree_map(lambda x: _global_array(np.asarray(x), replicated), model)
    std_r = _global_array(np.asarray(noise_std, np.float64), replicated)
    bar = _progress(sum(n_chunks.values()), progress)
    estimates = np.empty((len(lengths), realisations, true.size))
    codes = np.empty((len(lengths), realisations), np.int32)
    compile_s, run_s = np.zeros(len(lengths)), np.zeros(len(lengths))
    try:
        for i, n in enumerate(lengths):
            step = per_device[n] * n_dev
            compiled, compile_s[i] = _chunk_executable(
                model, design, n, noise, draws[n], estimator_fn, step, sharding, key)
            key_n = jax.random.fold_in(key, n)
            t0 = time.perf_counter()
            pending = []
            for c in range(n_chunks[n]):
                # Keys depend on (N, r) only: adding realisations or devices keeps old draws.
                idx = np.arange(c * step, (c + 1) * step)
                keys = jax.vmap(jax.random.fold_in, (None, 0))(key_n, idx)
                keys = _global_array(np.asarray(jax.random.key_data(keys)), sharding)
                # Dispatch is asynchronous: the next chunk is queued while this one runs.
                pending.append((idx, compiled(model_r, std_r, keys)))
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
        chunk_size=int(min(per_device.values())),
    )


def _collect(item, estimates, codes, realisations, bar):
    idx, (theta, code) = item
    keep = idx < realisations  # the last chunk is padded to keep one compiled shape
    estimates[idx[keep]] = _to_host(theta)[keep]
    codes[idx[keep]] = _to_host(code)[keep]
    if bar is not None:
        bar.update(1)
