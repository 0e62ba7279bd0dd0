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


def test_demo_checks_every_output_before_any_work(tmp_path, monkeypatch):
    # The second figure is in the way: refused at once, not after the whole run, and the
    # first figure is not left behind.
    import hbjax._cli.demo as demo

    def no_work(*args, **kwargs):
        raise AssertionError("the demo computed before checking its outputs")

    monkeypatch.setattr(demo, "simulate", no_work)
    (tmp_path / "v3_and_u.png").write_bytes(b"user's file")
    with pytest.raises(FileExistsError, match="`out`: .*v3_and_u.png.*--force"):
        run_demo(tmp_path, n_samples=2_000)
    assert [p.name for p in tmp_path.iterdir()] == ["v3_and_u.png"]
    # Bad arguments are refused, naming them, before the folder is created.
    with pytest.raises(ValueError, match=r"`n_samples` must be an integer >= 18, got 5"):
        run_demo(tmp_path / "new", n_samples=5)
    (tmp_path / "file").write_text("")
    with pytest.raises(NotADirectoryError, match="`out` must be a folder"):
        run_demo(tmp_path / "file", n_samples=2_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "v3_and_u.png"]


def test_demo_failure_removes_the_folders_it_created(tmp_path, monkeypatch):
    import hbjax._cli.demo as demo

    def fail(*args, **kwargs):
        raise RuntimeError("simulated failure")

    monkeypatch.setattr(demo, "refine", fail)
    with pytest.raises(RuntimeError, match="simulated failure"):
        run_demo(tmp_path / "a" / "b", n_samples=100)
    assert not (tmp_path / "a").exists()


def test_demo_command_names_its_options(tmp_path, capsys):
    from hbjax._cli.parser import main

    assert main(["demo", "--out", str(tmp_path / "dd"), "--samples", "5"]) == 1
    err = capsys.readouterr().err
    assert err == "hbjax demo: error: `--samples` must be an integer >= 18, got 5.\n"
    assert not (tmp_path / "dd").exists()
    (tmp_path / "true.json").write_text("{}")
    assert main(["demo", "--out", str(tmp_path / "true.json")]) == 1
    assert "`--out` must be a folder" in capsys.readouterr().err
