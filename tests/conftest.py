import os
import shutil
import subprocess
import sys
import tempfile

# One OpenBLAS thread per process. JAX's CPU LAPACK kernels (the QR of every
# Levenberg-Marquardt step, the Cholesky of refinement) run in scipy's OpenBLAS, whose
# idle threads spin; with two pytest workers on two cores (or any other work beside the
# run) each worker's BLAS threads compete with the other worker for the cores, and a
# diagnosis ran 5-10 times slower (tests/test_diagnose.py's study of 27 diagnoses beside
# one other busy process: 430 s with the default threads, 95 s with one; results
# bit-identical). Set before NumPy and OpenBLAS load; the workers and subprocesses inherit
# it. A user's own setting is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest

# The suite compiles thousands of programs and runs most of them once or a few times:
# XLA's CPU backend with LLVM's optimisation level 0 compiles them far faster (same HLO
# passes; measured on three compile-bound tests: 207 -> 158 s). Set before JAX starts its
# backend; the workers and subprocesses inherit it. A user's own XLA_FLAGS setting of it
# is kept. Benchmarks and users run the default level.
# XLA's older elemental emitters instead of its fusion emitters compile the diagnosis's
# programs in about 40% of the time (backend compile of three study diagnoses: 23 -> 9 s;
# the whole suite: 20:10 -> 15:32 on the 2-core machine, CPU 38 -> 29 min). Both emit the
# same operations; the order of a few floating-point sums differs, so results agree to
# rounding (a batched and an eager closed form, whose Vandermonde systems amplify rounding,
# to 1e-8 relative) -- not a setting for users: it slows `refine`'s first compile and the
# simulator (benchmarks/RESULTS.md, "Test suite duration"; docs/performance.md).
_XLA_TEST_FLAGS = {"--xla_backend_optimization_level": "0", "--xla_cpu_use_fusion_emitters": "false"}


def _xla_accepts(flags: str) -> bool:
    """Whether this jaxlib starts with ``flags`` (XLA aborts the process on a flag it does
    not know, and `pyproject.toml` allows jaxlib versions with and without the emitter
    flag): a one-line subprocess, once per run -- the workers inherit the result."""
    probe = subprocess.run([sys.executable, "-c", "import jax; jax.devices()"],
                           env=dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu"),
                           capture_output=True, timeout=300)
    return probe.returncode == 0


for _flag, _value in _XLA_TEST_FLAGS.items():
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        _flags = f"{os.environ.get('XLA_FLAGS', '')} {_flag}={_value}".strip()
        if _xla_accepts(_flags):
            os.environ["XLA_FLAGS"] = _flags

import jax  # noqa: E402


# One persistent compilation cache shared by the run's processes: the xdist workers and the
# subprocesses (notebooks, command line, demo, determinism jobs) compile many of the same
# programs, and the second compilation becomes a file read. It is kept between runs, in a
# directory of its own beside the user's hbjax cache (not in it: the suite's programs carry
# its compiler flags, which a user's never do), so that a run on an unchanged program
# reads the compiled code instead of compiling it again -- the suite's time is mostly
# compilation (benchmarks/RESULTS.md, "Test suite duration"). JAX keys every entry on the
# program, the flags, the backend and its own version, so a kept entry cannot change a
# result; past a size cap the oldest entries are removed when a run starts, and the
# directory can be deleted at any time. ``HBJAX_TEST_CACHE_DIR`` moves it; ``HBJAX_TEST_CACHE_DIR=run``
# gives each run a fresh temporary one, removed at the end. The cache's own behaviour is
# tested in fresh subprocesses (tests/test_cold_start.py), which set or clear these
# variables themselves.
_RUN_CACHE_OWNER = "HBJAX_TEST_RUN_CACHE"
_KEPT_CACHE_BYTES = 2 * 1024 ** 3


def _trim(path: str, cap: int = _KEPT_CACHE_BYTES) -> None:
    """Remove the oldest entries of the suite's own cache directory until it holds half of
    ``cap``, where it holds more (JAX's own size limit rescans the directory at every
    write, which thousands of entries make slow)."""
    entries = []
    with os.scandir(path) as it:
        for entry in it:
            # JAX's entries only: nothing else in a directory someone chose is touched
            if entry.name.endswith(("-cache", "-atime")) and entry.is_file(follow_symlinks=False):
                stat = entry.stat(follow_symlinks=False)
                entries.append((max(stat.st_atime, stat.st_mtime), stat.st_size, entry.path))
    total = sum(size for _, size, _ in entries)
    if total <= cap:
        return
    for _, size, file in sorted(entries):
        if total <= cap // 2:
            break
        try:
            os.remove(file)
            total -= size
        except OSError:  # another run removed it first
            pass


def _kept_cache_dir() -> str | None:
    """The directory kept between runs, or ``None`` where it cannot be written."""
    chosen = os.environ.get("HBJAX_TEST_CACHE_DIR", "").strip()
    if chosen == "run":
        return None
    if chosen:
        path = os.path.expanduser(chosen)
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "hbjax", "test-suite-jax")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:  # a read-only home: a cache for this run only
        return None
    return path if os.access(path, os.W_OK) else None


if not os.environ.get("HBJAX_CACHE_DIR") and not os.environ.get("HBJAX_NO_COMPILATION_CACHE"):
    _kept = _kept_cache_dir()
    if _kept is None:
        os.environ["HBJAX_CACHE_DIR"] = tempfile.mkdtemp(prefix="hbjax-test-cache-")
        os.environ[_RUN_CACHE_OWNER] = str(os.getpid())
    else:
        _trim(_kept)
        os.environ["HBJAX_CACHE_DIR"] = _kept


def pytest_unconfigure(config):
    if os.environ.get(_RUN_CACHE_OWNER) == str(os.getpid()):
        shutil.rmtree(os.environ["HBJAX_CACHE_DIR"], ignore_errors=True)


jax.config.update("jax_enable_x64", True)

import hbjax  # noqa: E402
from hbjax._core.mappings import mapping_count  # noqa: E402

# The longest test modules first (seconds of test time each in a full run on the 2-core
# machine, largest first): `make test` hands whole files to its two workers in collection
# order, and alphabetical order left four of the longest (test_refine*, test_robustness,
# test_validation_tools: about ten minutes) for the end of the run, where one worker could
# finish minutes before the other. Longest first is the classic remedy for that tail.
LONGEST_FIRST = (
    "test_refine.py", "test_diagnose.py", "test_notebooks.py", "test_diagnose_independent.py",
    "test_diagnose_level_cascade.py", "test_robustness.py", "test_validation_tools.py",
    "test_diagnose_physics.py", "test_refine_buckets.py", "test_identify_generalises.py",
    "test_diagnose_output_map.py",
    "test_output_unit.py", "test_giri_band.py", "test_fit_gauge.py", "test_fit.py",
    "test_architecture.py", "test_determinism.py", "test_refine_restarts.py",
    "test_docs_blocks.py", "test_adequacy.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    # a stable sort: the order inside each module is kept
    items.sort(key=lambda item: rank.get(os.path.basename(str(item.fspath)), len(rank)))


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
    if (mapping_count() or 0) > 30000:  # (None: not Linux, no mapping limit to watch)
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
