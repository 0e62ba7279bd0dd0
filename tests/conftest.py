import os

import jax
import numpy as np
import pytest


# The suite compiles hundreds of programs once each in one process: writing them all to the
# user's persistent compilation cache would only fill ~/.cache (and a crash inside JAX's
# executable serialisation, seen once in a clean-clone run, would take the whole suite down).
# The cache itself is tested in fresh subprocesses (tests/test_cold_start.py), which set or
# clear this variable themselves.
os.environ.setdefault("HBJAX_NO_COMPILATION_CACHE", "1")


jax.config.update("jax_enable_x64", True)

import hbjax  # noqa: E402


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
