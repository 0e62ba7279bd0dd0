"""`import hbjax` stays light and quiet: no tqdm (whose `tqdm.auto` warns "IProgress not
found" in a Jupyter kernel without ipywidgets), no pandas, no matplotlib, no `scipy.signal`
or `scipy.optimize` (together 1.2 s of a 3 s import, measured) until used; the structure
selection's bar goes through the shared progress policy."""

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

import hbjax


def test_import_hbjax_loads_no_tqdm_pandas_or_matplotlib():
    code = ("import sys, warnings\n"
            "warnings.simplefilter('error')\n"  # any warning on import fails
            "import hbjax\n"
            "print(sorted({m.split('.')[0] for m in sys.modules}"
            " & {'tqdm', 'pandas', 'matplotlib', 'ipywidgets'}"
            " | {m for m in sys.modules if m in ('scipy.signal', 'scipy.optimize')}))\n")
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
    assert proc.stderr == ""


def _recording():
    rng = np.random.default_rng(5)
    v = np.repeat(rng.uniform(-8, 8, 60), 5)
    y = hbjax.simulate(hbjax.default_system(), v, 0.05 * rng.standard_normal(300))
    return v, np.asarray(y)


def test_select_structure_bar_follows_the_progress_policy(capfd):
    sel = hbjax.select_structure(_recording(), na=2, nb=2, m=3, key=jax.random.PRNGKey(0),
                                 starts=2, progress={"delay": 0})
    err = capfd.readouterr().err
    assert "select_structure" in err and "1/1" in err
    assert sel.best == (2, 2, 3)


def test_select_structure_refuses_a_bad_progress_option():
    with pytest.raises(TypeError, match="progress"):
        hbjax.select_structure(_recording(), na=2, nb=2, m=3, key=jax.random.PRNGKey(0),
                               progress="yes")
