"""JAX's persistent compilation cache, switched on the first time hbjax compiles.

A fresh Python process recompiles every jitted function: for :func:`hbjax.refine`,
:func:`hbjax.fit` and :func:`hbjax.diagnose` that is seconds to tens of seconds on a
laptop CPU, each time. JAX can keep the compiled programs on disk, keyed on the program,
the backend, the compiler flags and the JAX version, so a second process loads them
instead. hbjax turns that cache on **lazily**, at the first call of a public entry point
(:func:`hbjax.simulate`, :func:`hbjax.refine`, :func:`hbjax.fit`, :func:`hbjax.diagnose`,
...) -- never on ``import hbjax`` -- through :func:`ensure_compilation_cache` below:

- if you configured a cache yourself (``jax.config.update("jax_compilation_cache_dir",
  ...)`` or the ``JAX_COMPILATION_CACHE_DIR`` environment variable), hbjax leaves it and
  its thresholds exactly as they are;
- if you disabled JAX's cache (``jax_enable_compilation_cache=False``) or set
  ``HBJAX_NO_COMPILATION_CACHE=1``, nothing happens;
- otherwise the cache goes to ``$HBJAX_CACHE_DIR`` or ``$XDG_CACHE_HOME/hbjax/jax``
  (default ``~/.cache/hbjax/jax``), and the minimum compile time and entry size are set
  to zero so small programs are cached too.

The cache cannot change results: a cached executable is the one the compiler produced
for the same program, flags and JAX version. The directory can be deleted at any time.
"""

import os
import threading
from pathlib import Path

import jax


ENV_DISABLE = "HBJAX_NO_COMPILATION_CACHE"
ENV_DIR = "HBJAX_CACHE_DIR"

_lock = threading.Lock()
_done = False
_directory: str | None = None


def default_cache_dir() -> Path:
    """``$HBJAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/hbjax/jax``, else
    ``~/.cache/hbjax/jax`` (``%LOCALAPPDATA%\\hbjax\\jax`` on Windows)."""
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME")
    if not base and os.name == "nt" and os.environ.get("LOCALAPPDATA"):
        base = os.environ["LOCALAPPDATA"]
    root = Path(base).expanduser() if base else Path.home() / ".cache"
    return root / "hbjax" / "jax"


def _disabled_by_env() -> bool:
    return os.environ.get(ENV_DISABLE, "").strip().lower() not in ("", "0", "false", "no")


def ensure_compilation_cache() -> str | None:
    """Turn JAX's persistent compilation cache on (once per process; cheap after that).

    **Returns:** the cache directory in use (the user's own or hbjax's), or ``None`` when
    the cache is off (disabled by the user or the directory could not be created).
    """
    global _done, _directory
    if _done:
        return _directory
    with _lock:
        if _done:
            return _directory
        _done = True
        if not jax.config.jax_enable_compilation_cache:
            return None
        configured = jax.config.jax_compilation_cache_dir
        if configured:  # the user's cache and thresholds win
            _directory = str(configured)
            return _directory
        if _disabled_by_env():
            return None
        path = default_cache_dir()
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError:  # read-only home, no permission: run uncached
            return None
        jax.config.update("jax_compilation_cache_dir", str(path))
        # JAX's defaults skip programs compiling in under a second; most of hbjax's are
        # smaller but there are many of them, and their sum is the cold start.
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
        _directory = str(path)
        return _directory


def compilation_cache_dir() -> str | None:
    """The persistent compilation cache directory hbjax uses, turning the cache on first
    if no hbjax function has run yet (see ``docs/performance.md``); ``None`` when it is
    off (``HBJAX_NO_COMPILATION_CACHE=1`` or ``jax_enable_compilation_cache=False``)."""
    return ensure_compilation_cache()
