"""Progress bars: silent with progress=False, shown for long-enough work with progress=True
(forced here off a terminal with a dict of tqdm options and no delay)."""

import jax
import numpy as np
import pytest

import hbjax


@pytest.fixture(scope="module")
def recording():
    model = hbjax.default_system()
    rng = np.random.default_rng(3)
    n = 600
    v = np.repeat(rng.uniform(-8, 8, n // 5), 5)
    y = hbjax.simulate(model, v, 0.05 * rng.standard_normal(n))
    return v, np.asarray(y)


def _fit(recording, progress):
    return hbjax.fit(recording, na=2, nb=2, m=3, key=jax.random.PRNGKey(0), starts=4,
                     progress=progress)


def test_progress_false_prints_nothing(recording, capfd):
    _fit(recording, False)
    out, err = capfd.readouterr()
    assert err == "" and out == ""


def test_progress_bar_shown_for_long_enough_work(recording, capfd):
    _fit(recording, {"delay": 0})
    err = capfd.readouterr().err
    assert "fit" in err and "4/4" in err and "start" in err


def test_default_progress_is_quiet_off_a_terminal(recording, capfd):
    # pytest's captured stderr is not a terminal: the default bar stays off (logs, CI)
    _fit(recording, True)
    assert capfd.readouterr().err == ""


def test_bad_progress_refused(recording):
    with pytest.raises(TypeError, match="progress"):
        _fit(recording, "yes")
