"""Input validation shared by the public entry points.

Shapes and types are checked in Python (at trace time) with messages naming the
argument; values are checked eagerly when concrete and with ``eqx.error_if`` when traced.
"""

import statistics

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import betainc, gammaincc


def is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def as_float_array(x, name: str, ndim: int | None = None, *, dtype=None, host: bool = False):
    """Convert ``x`` to a real floating JAX array, naming ``name`` in any error.

    Floating inputs keep their precision (float32 stays float32 for training pipelines);
    integers and booleans become JAX's default float. Estimators pass ``dtype=jnp.float64``
    after :func:`hbjax._core.precision.require_x64`. ``host=True`` returns data that is not
    already a JAX array as a NumPy array (same checks), for callers that still edit it on
    the host before one transfer to the device.
    """
    if isinstance(x, (str, bytes)) or x is None:
        raise TypeError(f"`{name}` must be a numeric array, got {type(x).__name__}.")
    if not is_traced(x):
        try:
            arr = np.asarray(x)
        except ValueError:  # ragged nested sequences
            raise ValueError(
                f"`{name}` must be a numeric array of regular shape, got a ragged sequence."
            ) from None
        # (jnp.issubdtype also knows the ML float types NumPy does not, such as bfloat16)
        if arr.dtype == object or not (
            np.issubdtype(arr.dtype, np.number) or arr.dtype == bool
            or jnp.issubdtype(arr.dtype, jnp.floating)
        ):
            raise TypeError(f"`{name}` must be a numeric array, got dtype {arr.dtype}.")
        if np.iscomplexobj(arr):
            raise TypeError(f"`{name}` must be real, got complex dtype {arr.dtype}.")
    elif not (jnp.issubdtype(x.dtype, jnp.floating) or jnp.issubdtype(x.dtype, jnp.integer)
              or x.dtype == jnp.bool_):
        # A traced array is checked by its dtype at trace time: a complex (or key) tracer
        # would otherwise flow on, or be cast to its real part by a later astype.
        kind = "real, got complex" if jnp.issubdtype(x.dtype, jnp.complexfloating) else \
            "a numeric array, got"
        raise TypeError(f"`{name}` must be {kind} dtype {x.dtype}.")
    if not is_traced(x) and not isinstance(x, jax.Array) and jnp.issubdtype(arr.dtype,
                                                                            jnp.floating):
        # a finite value the computing dtype cannot hold would become inf, and be refused
        # as if the data held one (64-bit floats off: float64 data is computed in float32)
        target = np.dtype(dtype) if dtype is not None else np.dtype(
            jax.dtypes.canonicalize_dtype(arr.dtype))
        narrower = jnp.issubdtype(target, jnp.floating) and target.itemsize < arr.itemsize
        finite = np.abs(arr[np.isfinite(arr)]) if (arr.size and narrower) else np.zeros(0)
        if finite.size and float(
                np.max(finite)) > float(jnp.finfo(target).max):
            raise ValueError(
                f"`{name}` reaches a magnitude of {float(np.max(finite)):.3g}, beyond the "
                f"largest {target} ({float(jnp.finfo(target).max):.3g}) it is computed in"
                + (" (64-bit floats are off: jax.config.update('jax_enable_x64', True))"
                   if target == np.float32 and not jax.config.jax_enable_x64 else "") + ".")
    # NumPy operations on host data that stays there; JAX's otherwise (same casts, same check).
    on_host = host and not is_traced(x) and not isinstance(x, jax.Array)
    xp = np if on_host else jnp
    out = arr if on_host else jnp.asarray(x)
    if dtype is not None:
        # (a host array already of `dtype` is not copied: no caller edits it in place)
        out = out.astype(dtype, copy=False) if on_host else out.astype(dtype)
    elif not xp.issubdtype(out.dtype, xp.inexact):
        out = out.astype(jnp.result_type(float))
    if ndim is not None and out.ndim != ndim:
        raise ValueError(
            f"`{name}` must be a {ndim}-D array, got shape {tuple(out.shape)}."
        )
    return out


def check_finite(x: jax.Array, name: str) -> jax.Array:
    """Refuse NaN/inf: eagerly when concrete, with ``eqx.error_if`` under jit."""
    if is_traced(x):
        return eqx.error_if(x, ~jnp.all(jnp.isfinite(x)), f"`{name}` contains NaN or inf.")
    bad = np.flatnonzero(~np.isfinite(np.asarray(x)))
    if bad.size:
        raise ValueError(
            f"`{name}` contains NaN or inf ({bad.size} samples, first at index {bad[0]})."
        )
    return x


# Squares of the samples enter every least-squares sum: beyond about 1e154 they overflow
# float64. 1e100 leaves room for the sums over long records and the polynomial powers; its
# inverse is the floor below which the squares underflow (a nonzero peak under 1e-100).
MAX_MAGNITUDE = 1e100


def check_magnitude(x, name: str, limit: float = MAX_MAGNITUDE, *, output: bool = False):
    """Refuse a concrete record whose samples are too large for the estimators' sums of
    squares (they would overflow to inf and surface as a numerical failure elsewhere);
    an estimator's `output` also when its nonzero samples are all below ``1 / limit`` (the
    estimate's variances carry the output's unit squared and would underflow to 0)."""
    if is_traced(x):
        return x
    peak = float(np.max(np.abs(np.asarray(x)))) if np.size(x) else 0.0
    if not np.isfinite(peak):  # NaN or inf is no magnitude: say where it is
        check_finite(x, name)
    if peak > limit:
        raise ValueError(
            f"`{name}` reaches a magnitude of {peak:.3g}; the estimators form sums of "
            f"squares, which overflow float64 beyond about 1e154: rescale `{name}` (and the "
            f"model) to units where its samples stay below {limit:.0e}."
        )
    if output and 0.0 < peak < 1.0 / limit:
        raise ValueError(
            f"`{name}` reaches a magnitude of only {peak:.3g}; the estimators' variances are "
            f"squares of it, which underflow to 0 below about 1e-154: rescale `{name}` (and "
            f"the model) to units where its largest sample is above {1.0 / limit:.0e}."
        )
    return x


def check_values(x, name: str, limit: float = MAX_MAGNITUDE, *, output: bool = False):
    """:func:`check_finite` then :func:`check_magnitude`; concrete data that pass both cost
    two reductions (max and min, which NaN and inf fail), not the four passes of the two."""
    if not is_traced(x) and np.size(x):
        arr = np.asarray(x)
        peak = max(float(np.max(arr)), -float(np.min(arr)))
        if peak <= limit and not (output and 0.0 < peak < 1.0 / limit):  # (False for NaN)
            return x
    return check_magnitude(check_finite(x, name), name, limit, output=output)


def float_dtype(*trees):
    """The floating dtype a computation on these arrays/pytrees runs in (NumPy promotion of
    their floating leaves; JAX's default float when there are none)."""
    leaves = [x for t in trees for x in jax.tree_util.tree_leaves(t)
              if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.inexact)]
    return jnp.result_type(*leaves) if leaves else jnp.result_type(float)


def signal(x, name: str, *, min_length: int = 1, finite: bool = True) -> jax.Array:
    """A 1-D floating time series of at least ``min_length`` samples, checked finite
    (``finite=False`` leaves a traced array's check to :func:`guard_finite`)."""
    arr = as_float_array(x, name, ndim=1)
    if arr.shape[0] < min_length:
        raise ValueError(
            f"`{name}` must have at least {min_length} samples, got {arr.shape[0]}."
        )
    if finite or not is_traced(arr):
        return check_finite(arr, name)
    return arr


def guard_finite(carrier: jax.Array, **arrays) -> jax.Array:
    """Attach ``eqx.error_if`` finiteness checks of traced ``arrays`` to the small array
    ``carrier`` (e.g. an initial state) instead of to the arrays themselves.

    Guarding a whole record forces a copy of it (and, under ``vmap``, of every batch
    element), which tripled the simulator's run time; a scalar the computation depends
    on carries the same check for free.
    """
    for name, x in arrays.items():
        if is_traced(x):
            carrier = eqx.error_if(
                carrier, ~jnp.all(jnp.isfinite(x)), f"`{name}` contains NaN or inf."
            )
    return carrier


def one_device(**trees) -> None:
    """Refuse concrete arrays committed to different devices (JAX's own message names
    internal argument paths): say which argument lives where and how to fix it."""
    where = {}
    for name, tree in trees.items():
        for leaf in jax.tree_util.tree_leaves(tree):
            if isinstance(leaf, jax.Array) and not is_traced(leaf) and leaf.committed:
                where.setdefault(frozenset(leaf.devices()), name)
    if len(where) > 1:
        desc = "; ".join(f"`{name}` on {', '.join(sorted(str(d) for d in devs))}"
                         for devs, name in where.items())
        raise ValueError(
            f"arrays live on different devices ({desc}): put them on one device first, "
            "e.g. with jax.device_put(x, device)."
        )


def same_length(**arrays) -> None:
    lengths = {k: int(v.shape[0]) for k, v in arrays.items()}
    if len(set(lengths.values())) > 1:
        desc = ", ".join(f"`{k}` has {n}" for k, n in lengths.items())
        raise ValueError(f"records must have equal lengths: {desc} samples.")


def positive_int(x, name: str, *, minimum: int = 1) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        raise TypeError(f"`{name}` must be an integer, got {x!r}.")
    if x < minimum:
        raise ValueError(f"`{name}` must be an integer >= {minimum}, got {x}.")
    return int(x)


def check_bool(x, name: str) -> bool:
    """A flag of the public API (``throw``, ``overwrite``, ...): a Python or NumPy bool,
    returned as ``bool``. Checked in Python at the function's entry (a static argument):
    a string such as ``"false"`` is truthy and an integer may be a slip for another
    argument, so anything else raises a ``TypeError`` naming ``name``."""
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    raise TypeError(f"`{name}` must be True or False, got {x!r}.")


def positive_float(x, name: str, *, allow_zero: bool = False) -> float:
    """A concrete finite number > 0 (or >= 0 with `allow_zero`): an amplitude such as
    ``h_m``, a noise level, a solver tolerance."""
    # Strings and booleans convert with float() but are not amplitudes.
    if isinstance(x, (str, bytes, bool, np.bool_)):
        raise TypeError(f"`{name}` must be a real number, got {x!r}.")
    try:
        val = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"`{name}` must be a real number, got {x!r}.") from None
    if not np.isfinite(val) or val < 0 or (val == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"`{name}` must be a finite number {bound}, got {x!r}.")
    return val


def is_real_scalar(x) -> bool:
    """A Python or NumPy real number (``np.float32(0.3)``, ``np.int64(2)``), not a bool: the
    scalars a float argument such as a fraction accepts (complex, strings, arrays are not)."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)


def fraction(x, name: str) -> float:
    """A concrete real number strictly between 0 and 1 (a share of a record, such as
    ``holdout``), returned as ``float``."""
    if not is_real_scalar(x):
        raise TypeError(f"`{name}` must be a fraction in (0, 1), got {x!r}.")
    if not 0 < x < 1:  # (False for NaN)
        raise ValueError(f"`{name}` must be a fraction in (0, 1), got {x!r}.")
    return float(x)


def lagged(x, lag: int):
    """``x(t - lag)`` along the first (time) axis of an array of any rank, with
    ``x(t) = 0`` for ``t < 0`` (the zero initial conditions): the shift ``q^-lag`` of the
    ARX block, eq. (2)."""
    if lag == 0:
        return x
    if lag >= x.shape[0]:  # a record shorter than the lag sees only initial conditions
        return jnp.zeros_like(x)
    return jnp.concatenate([jnp.zeros((lag,) + x.shape[1:], x.dtype), x[:-lag]])


def lag_sum(coef, x):
    """``sum_i coef[i] x(t - 1 - i)`` along the first axis of ``x`` (zero before ``t = 0``):
    a polynomial in ``q^-1`` without its constant term applied to ``x``, e.g.
    ``B(q^-1) u`` or ``(A(q^-1) - 1) y`` of eq. (2). A coefficient may be a number or a
    per-sample array of length ``T`` (a coefficient that changes in time); it multiplies
    every column of a 2-D ``x``. The one home of these sums (criteria, diagnosis kernel,
    effects)."""
    out = jnp.zeros_like(x)
    for i in range(len(coef)):
        c = jnp.asarray(coef[i])
        c = c.reshape(c.shape + (1,) * (x.ndim - c.ndim)) if c.ndim else c
        out = out + c * lagged(x, i + 1)
    return out


def jsonable(x):
    """``x`` with arrays as nested lists, NumPy/JAX scalars as Python numbers, NaN/inf as
    ``None`` (JSON has no non-finite numbers) and dict keys as strings, recursively."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jax.Array)):
        return jsonable(np.asarray(x).tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if np.isfinite(x) else None
    return x


def check_key(key, name: str = "key", *, optional: bool = False):
    """A single JAX PRNG key, returned unchanged: a typed key (``jax.random.key(0)``) or a
    legacy ``uint32`` key of shape ``(2,)`` (``jax.random.PRNGKey(0)``); also ``None``
    with ``optional``. Anything else (an integer seed, a NumPy generator, a batch of
    keys, a float array) raises a ``TypeError`` naming what was given."""
    if key is None and optional:
        return None
    if isinstance(key, jax.Array) and (
            (jnp.issubdtype(key.dtype, jax.dtypes.prng_key) and key.shape == ())
            or (key.dtype == jnp.uint32 and key.shape == (2,))):
        return key
    if hasattr(key, "dtype") and hasattr(key, "shape"):
        what = f"{type(key).__name__} of dtype {key.dtype} and shape {tuple(key.shape)}"
    else:
        what = f"{type(key).__name__} {key!r}"
    raise TypeError(
        f"`{name}` must be a single JAX PRNG key (jax.random.key(0) or "
        f"jax.random.PRNGKey(0)){' or None' if optional else ''}, got {what}."
    )


def chi2_sf(x, dof):
    """Survival function of the chi-square distribution with ``dof`` degrees of freedom
    (at least 1): traceable (``x``, ``dof`` may be traced), NaN for a NaN statistic, 0 for
    an infinite one. The one home of the residual tests' p-values: the compiled checks
    inside every refinement and the NumPy reports (``float(chi2_sf(...))``) share it."""
    x = jnp.asarray(x, jnp.result_type(float))
    dof = jnp.maximum(jnp.asarray(dof, x.dtype), 1.0)
    p = jnp.where(x > 0, gammaincc(dof / 2.0, jnp.maximum(x, 0.0) / 2.0), 1.0)
    return jnp.where(jnp.isnan(x), jnp.nan, p)


def holds_real_numbers(dtype) -> bool:
    """Whether a column's ``dtype`` holds real numbers (integers or floats): the one test
    behind every DataFrame column read as float64, so that a complex column never loses
    its imaginary part and a text column is never parsed."""
    return getattr(dtype, "kind", "O") in "iuf"


def t_quantile(q: float, dof: int) -> float:
    """The ``q`` quantile (``q`` in (0.5, 1)) of Student's t distribution with ``dof``
    degrees of freedom (at least 1), by bisection on its distribution function
    ``1 - I_{dof / (dof + t^2)}(dof / 2, 1 / 2) / 2``: the factor of a mean's confidence
    interval over few realisations (12.71 at one degree of freedom, 1.96 in the limit).
    A NumPy float (for reports)."""
    dof = float(max(int(dof), 1))
    if dof >= 30:
        # Cornish-Fisher expansion in 1 / dof (Abramowitz & Stegun 26.7.5): exact to 1e-6
        # here, where the incomplete beta function of float32 is not.
        z = statistics.NormalDist().inv_cdf(q)
        g = ((z**3 + z) / 4, (5 * z**5 + 16 * z**3 + 3 * z) / 96,
             (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384)
        return z + g[0] / dof + g[1] / dof**2 + g[2] / dof**3

    def cdf(t):
        return 1.0 - 0.5 * float(betainc(dof / 2.0, 0.5, dof / (dof + t * t)))

    lo, hi = 0.0, 1.0
    while cdf(hi) < q:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < q else (lo, mid)
    return 0.5 * (lo + hi)


def no_spread(y: np.ndarray, eps: float | None = None) -> bool:
    """Whether ``y`` is constant up to rounding (``eps``: that of the data as given, by
    default its dtype's), so that a fit percentage relative to its spread is undefined
    and there is no response to identify or diagnose. Judged on the peak-to-peak range,
    exact in floating point: the mean subtracted from a constant record leaves rounding
    noise that would divide the error. The one test of an output (or input) that never
    moves for ``fit``, ``refine``, ``compare``, ``select_structure`` and ``diagnose``; the
    traced free-run fit (``_identify/quality.py``) applies the same rule in ``jnp``."""
    y = np.asarray(y)
    if eps is None:
        eps = np.finfo(y.dtype if np.issubdtype(y.dtype, np.floating) else float).eps
    return bool(np.ptp(y) <= 4 * eps * np.max(np.abs(y)))
