"""Fast cold starts: the persistent compilation cache (turned on lazily by the first hbjax
call, in a per-user directory, respecting the user's own cache, off by an environment
variable) and length buckets (an eager record is padded to a bucket and the first N samples
returned, identical to the unpadded run). No timings here: benchmarks/cold_start.py."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax


SCRIPT = textwrap.dedent("""
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    import hbjax
    print("after import:", jax.config.jax_compilation_cache_dir)
    hbjax.simulate(hbjax.default_system(), np.ones(7))
    print("after simulate:", jax.config.jax_compilation_cache_dir)
    print("hbjax says:", hbjax.compilation_cache_dir())
    print("min compile time:", jax.config.jax_persistent_cache_min_compile_time_secs)
""")


def _run(tmp_path, **env):
    clean = {k: v for k, v in os.environ.items()
             if k not in ("JAX_COMPILATION_CACHE_DIR", "HBJAX_CACHE_DIR",
                          "HBJAX_NO_COMPILATION_CACHE")}
    clean.update(JAX_PLATFORMS="cpu", XDG_CACHE_HOME=str(tmp_path / "xdg"), **env)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=clean, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return dict(line.split(": ", 1) for line in out.stdout.strip().splitlines())


def _entries(path):
    return sorted(os.listdir(path)) if path.is_dir() else []


def test_cache_on_first_use_in_per_user_directory(tmp_path):
    lines = _run(tmp_path)
    where = tmp_path / "xdg" / "hbjax" / "jax"
    assert lines["after import"] == "None"  # import hbjax changes no global setting
    assert lines["after simulate"] == str(where) == lines["hbjax says"]
    assert any("simulate" in name for name in _entries(where))
    assert float(lines["min compile time"]) == 0.0  # small programs are cached too


def test_environment_variable_turns_cache_off(tmp_path):
    lines = _run(tmp_path, HBJAX_NO_COMPILATION_CACHE="1")
    assert lines["after simulate"] == "None" and lines["hbjax says"] == "None"
    assert not (tmp_path / "xdg" / "hbjax").exists()


def test_user_configured_cache_is_respected(tmp_path):
    mine = tmp_path / "mine"
    lines = _run(tmp_path, JAX_COMPILATION_CACHE_DIR=str(mine))
    assert lines["after simulate"] == str(mine) == lines["hbjax says"]
    assert not (tmp_path / "xdg" / "hbjax").exists()
    # the user's thresholds are left alone (JAX's default: 1 s of compile time)
    assert float(lines["min compile time"]) == 1.0


def test_hbjax_cache_dir_variable(tmp_path):
    lines = _run(tmp_path, HBJAX_CACHE_DIR=str(tmp_path / "elsewhere"))
    assert lines["after simulate"] == str(tmp_path / "elsewhere")
    assert any("simulate" in name for name in _entries(tmp_path / "elsewhere"))


@pytest.mark.parametrize("n", [1, 7, 256, 257, 1000, 1023, 1500])
def test_bucketed_records_equal_unpadded_runs(n):
    model = hbjax.default_system()
    rng = np.random.default_rng(n)
    v = rng.uniform(-8, 8, n)
    xi = 0.1 * rng.standard_normal(n)
    y0 = np.array([0.3, -0.2])
    # Under jit the record is traced and never padded: the reference.
    sim = jax.jit(lambda v, xi: hbjax.simulate(model, v, xi, u0=0.5, y0=y0))
    pred = jax.jit(lambda v, y: hbjax.predict(model, v, y, u0=0.5))
    play = jax.jit(lambda v: hbjax.play(model.backlash, v, u0=0.5))
    y = hbjax.simulate(model, v, xi, u0=0.5, y0=y0)
    assert y.shape == (n,)
    np.testing.assert_allclose(y, sim(v, xi), rtol=0, atol=1e-12)
    np.testing.assert_allclose(hbjax.predict(model, v, y, u0=0.5), pred(v, y), rtol=0, atol=1e-12)
    np.testing.assert_allclose(hbjax.play(model.backlash, v, u0=0.5), play(v), rtol=0, atol=1e-12)


def test_bucket_padding_never_reports_a_divergence_of_the_tail():
    # Unstable linear block (pole 10): the first 40 samples are finite, the padded tail
    # (256 samples) would overflow.
    unstable = hbjax.Hammerstein(hbjax.default_system().backlash, hbjax.ARX([-10.0], [1.0]))
    y = hbjax.simulate(unstable, np.ones(40) * 3.0)
    assert y.shape == (40,) and bool(jnp.all(jnp.isfinite(y)))
    with pytest.raises(ValueError, match="overflows"):
        hbjax.simulate(unstable, np.ones(2000) * 3.0)


def test_suite_cache_trim_removes_only_the_oldest_cache_entries(tmp_path):
    # The test suite keeps its compilation cache between runs (tests/conftest.py) and trims
    # it when a run starts: the oldest entries go first, down to half the cap, and nothing
    # but JAX's own entries is ever removed from the directory.
    from conftest import _trim

    for i in range(6):
        entry = tmp_path / f"jit_f-{i}-cache"
        entry.write_bytes(b"x" * 100)
        os.utime(entry, (1000 + i, 1000 + i))
    (tmp_path / "notes.txt").write_bytes(b"y" * 1000)
    _trim(str(tmp_path), cap=1000)  # 600 bytes of entries: under the cap, nothing goes
    assert len(list(tmp_path.glob("*-cache"))) == 6
    _trim(str(tmp_path), cap=500)  # over: the oldest go until at most 250 bytes are left
    assert sorted(p.name for p in tmp_path.glob("*-cache")) == ["jit_f-4-cache", "jit_f-5-cache"]
    assert (tmp_path / "notes.txt").read_bytes() == b"y" * 1000
