"""The main job (`make demo`, `hbjax demo`) runs, reports and writes its figures."""

import numpy as np
import pytest

import hbjax
from hbjax._cli.demo import run_demo


def test_demo_reports_and_writes_figures(tmp_path, capsys):
    result, refined = run_demo(tmp_path, n_samples=2_000)
    out = capsys.readouterr().out
    for name in hbjax.param_names(result.model):
        assert f" {name} " in out
    assert "validation fit" in out
    for figure in ("backlash_loop.png", "v3_and_u.png", "measured_vs_simulated.png"):
        assert (tmp_path / figure).stat().st_size > 1000
    # The refined estimate is within a few of its own standard errors of the truth.
    truth = hbjax.normalise(hbjax.default_system(), hbjax.default_design().h_m)
    err = np.asarray(hbjax.flatten_params(refined.model) - hbjax.flatten_params(truth))
    assert refined.message == "success"
    assert np.all(np.abs(err) <= 5 * np.asarray(refined.std) + 1e-12)


def test_demo_never_overwrites_figures_unless_forced(tmp_path):
    (tmp_path / "backlash_loop.png").write_bytes(b"user's file")
    with pytest.raises(FileExistsError, match="--force"):
        run_demo(tmp_path, n_samples=2_000)
    assert (tmp_path / "backlash_loop.png").read_bytes() == b"user's file"
    run_demo(tmp_path, n_samples=2_000, force=True)
    assert (tmp_path / "backlash_loop.png").read_bytes() != b"user's file"
