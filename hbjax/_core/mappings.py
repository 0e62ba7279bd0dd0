"""Compiled programs against Linux's cap on a process's memory mappings.

Every compiled XLA:CPU program keeps its machine code in memory mappings of its own, and
JAX keeps every program it compiled for the life of the process. Linux caps a process at
``vm.max_map_count`` mappings (65530 by default); at the cap the next compilation fails
inside LLVM ("Cannot allocate memory") and the process crashes. Diagnosing recordings of
many different lengths in one session reaches it: measured, two processes each diagnosing
about 40 random recordings of 1000-8000 samples both crashed this way. The heavy entry
points (:func:`hbjax.diagnose`, :func:`hbjax.fit`, :func:`hbjax.monte_carlo`) therefore
call :func:`release_compiled_programs` first, which drops JAX's compiled programs (they
are compiled again, or read from the persistent compilation cache, when next needed) once
the process holds more than half of its allowance.
"""

import functools
import warnings

import jax

# Of the kernel's cap: room left for the programs of the call about to run (a diagnosis
# compiles a few thousand mappings' worth).
_FRACTION = 0.5


def mapping_count() -> int | None:
    """The process's memory mappings, or ``None`` where ``/proc`` does not tell."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return maps.read().count(b"\n")
    except OSError:
        return None


@functools.cache
def mapping_limit() -> int | None:
    """``vm.max_map_count``, or ``None`` where ``/proc`` does not tell (read once)."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def release_compiled_programs(count: int | None = None, limit: int | None = None) -> bool:
    """Drop JAX's compiled programs (``jax.clear_caches()``) if the process holds more than
    half of its allowed memory mappings, with a warning; returns whether it did.
    ``count`` and ``limit`` default to the process's own figures."""
    limit = mapping_limit() if limit is None else limit
    if limit is None:
        return False
    count = mapping_count() if count is None else count
    if count is None or count <= _FRACTION * limit:
        return False
    jax.clear_caches()
    warnings.warn(
        f"hbjax: this process holds {count} memory mappings of the {limit} Linux allows "
        "(vm.max_map_count), most of them compiled programs; JAX's compiled programs were "
        "dropped so that the next compilation cannot crash. They are compiled again (or read "
        "from the compilation cache) when next needed.",
        RuntimeWarning, stacklevel=3,
    )
    return True
