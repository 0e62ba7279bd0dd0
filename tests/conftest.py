import os

import jax
import numpy as np
import pytest


# The suite compiles thousands of programs in one process: writing them all to the user's
# persistent compilation cache would only fill ~/.cache. The cache itself is tested in fresh
# subprocesses (tests/test_cold_start.py), which set or clear this variable themselves.
os.environ.setdefault("HBJAX_NO_COMPILATION_CACHE", "1")


jax.config.update("jax_enable_x64", True)

import hbjax  # noqa: E402


def _mapping_count() -> int:
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:  # not Linux: no per-process mapping limit to watch
        return 0


@pytest.fixture(autouse=True)
def _free_compiled_programs():
    """Drop JAX's compiled programs when the process holds many memory mappings.

    Each XLA:CPU executable keeps its machine code in memory mappings of its own; the suite
    compiles thousands of programs in one process, and without this the process reaches the
    kernel's per-process limit (``vm.max_map_count``, 65530 by default: measured, the count
    grew by about 2000 a minute through the diagnosis tests and the crash came at 65215)
    and the next compilation dies inside LLVM with a segmentation fault. Clearing only past
    a high-water mark keeps the programs that later tests share."""
    yield
    if _mapping_count() > 30000:
        jax.clear_caches()


@pytest.fixture
def system():
    return hbjax.default_system()


@pytest.fixture
def design():
    return hbjax.default_design()


def reference_simulate(c1, c2, a, b, v, xi, u0=0.0):
    """Independent plain-NumPy loop of the NOTES.md conventions (no JAX)."""
    c1, c2, a, b = (np.asarray(x, float) for x in (c1, c2, a, b))
    T = len(v)
    y, u = np.zeros(T), np.zeros(T)
    state = float(u0)
    for t in range(T):
        p1 = sum(c * v[t] ** i for i, c in enumerate(c1))
        p2 = sum(c * v[t] ** i for i, c in enumerate(c2))
        state = min(max(state, min(p1, p2)), max(p1, p2))
        u[t] = state
        acc = xi[t]
        for i in range(len(a)):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for i in range(len(b)):
            if t - 1 - i >= 0:
                acc += b[i] * u[t - 1 - i]
        y[t] = acc
    return y, u
