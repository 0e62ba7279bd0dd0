"""Record lengths rounded up to a few compiled sizes ("buckets").

XLA compiles one program per array shape, so every new record length costs a fresh
compilation (about a second for the simulator, several for refinement). The causal
computations -- play operator, free run, one-step prediction -- give the same first ``N``
samples whatever follows them, so an eager call pads its record to the next bucket, runs
the program compiled for that bucket, and returns the first ``N`` samples. Results are
unaffected (the same arithmetic on the same samples); only the padded tail is extra work,
at most 25% (12.5% on average) above :data:`MIN_BUCKET` samples.

The estimators (:func:`hbjax.refine`) pad their records the same way and carry the
recorded length as a runtime value (:func:`padded_records`): their sums over samples are
masked, so padded samples contribute nothing.

Buckets are ``k * 2^e`` with ``k in {4, 5, 6, 7}``: four per octave. Calls under
``jax.jit`` / ``vmap`` / ``grad`` (a traced record, model or state) are never padded: the
caller's own program fixes the shape.
"""

import jax
import numpy as np

from .._misc import is_traced


#: records up to this length all share one program
MIN_BUCKET = 256


def bucket_length(n: int) -> int:
    """The smallest bucket holding ``n`` samples."""
    if n <= MIN_BUCKET:
        return MIN_BUCKET
    e = (n - 1).bit_length() - 3  # 2^(e+2) < n <= 2^(e+3)
    step = 1 << e
    return -(-n // step) * step


def should_bucket(*trees) -> bool:
    """Pad only when nothing is traced (an eager call from user code): a traced model,
    state or record means an enclosing jit/vmap/grad whose program fixes the shapes."""
    return not any(is_traced(x) for x in jax.tree_util.tree_leaves(trees))


def pad(x, length: int) -> jax.Array:
    """Concrete ``x`` with zeros appended up to ``length`` samples, padded on the host and
    placed with ``device_put`` (an eager ``jnp`` op would compile once per length) on the
    device ``x`` was committed to, if any."""
    return jax.device_put(padded(x, length), _committed_device(x))


def padded(x, length: int, *, hold: bool = False) -> np.ndarray:
    """``x`` on the host, extended to ``length`` samples with zeros, or with its last value
    repeated (``hold=True``: a held input and output keep the padded part of every
    recursion finite, where the padding is masked out or cut off rather than zero)."""
    x = np.asarray(x)
    # (np.pad took 17.6 us for a 10 000-sample record, this 3.3 us; a refinement pads each
    # of its records' two signals)
    out = np.empty(length, x.dtype)
    out[:x.shape[0]] = x
    out[x.shape[0]:] = x[-1] if hold and x.shape[0] else 0
    return out


def _committed_device(x):
    """The device a concrete JAX array was committed to, else ``None`` (JAX's default)."""
    if isinstance(x, jax.Array) and x.committed:
        return next(iter(x.devices()))
    return None


def padded_records(recordings) -> tuple:
    """Concrete ``(v, y)`` records -> padded records ``(v, y, n)``: both signals zero-padded
    to the bucket of their length ``n``, and ``n`` as an integer array (a runtime value, so
    one compiled estimator serves every length of a bucket). The estimators mask every
    sum, extremum and count over samples with ``n``
    (:func:`hbjax._identify.criteria.unpack`), which makes the padding invisible in their
    results; the recursions are causal, so the recorded samples are computed as without it.
    """
    host, devices = [], []
    for v, y in recordings:
        n = int(v.shape[0])
        size = bucket_length(n)
        host.append((padded(v, size), padded(y, size), np.asarray(n)))
        devices.append(_committed_device(v))
    # Records on no committed device stay NumPy arrays: the jitted estimator transfers its
    # arguments in its C++ dispatch, faster than a `device_put` from Python (0.4 ms of a
    # 7 ms refinement). Otherwise one transfer for all records where they share a device.
    if devices == [None] * len(devices):
        return tuple(host)
    if len(set(devices)) == 1:
        return tuple(jax.device_put(tuple(host), devices[0]))
    return tuple(jax.device_put(rec, device) for rec, device in zip(host, devices))
