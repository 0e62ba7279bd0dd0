"""The command-line tool end to end, through subprocesses on small files."""

import argparse
import json
import os
import pathlib
import re
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._cli.parser import build_parser, main

ENV = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONWARNINGS": "ignore"}


def run(*args, cwd, check=True):
    proc = subprocess.run(
        [sys.executable, "-m", "hbjax", *map(str, args)],
        cwd=cwd, env=ENV, capture_output=True, text=True, timeout=300,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"hbjax {args} failed ({proc.returncode}):\n{proc.stderr}")
    return proc


def test_paper_workflow_signals_simulate_identify(tmp_path, system, design):
    hbjax.save_model(tmp_path / "true.json", system)
    run("signals", "--design", "n=2,m=3,h_m=4", "--samples", 3000, "--prefix", "v", cwd=tmp_path)
    for k in (1, 2, 3):
        run("simulate", "--model", "true.json", "--input", f"v{k}.csv", "--out", f"y{k}.csv",
            "--noise-std", 0.05, "--seed", k, cwd=tmp_path)
    # The CLI's input signals are the design's signals, and its outputs the library's simulation.
    rec = hbjax.load_recording(tmp_path / "y3.csv")
    np.testing.assert_array_equal(rec.v, design.staircase_input(3000))
    proc = run("identify", "giri", "--design", "n=2,m=3,h_m=4", "y1.csv", "y2.csv", "y3.csv",
               "--out", "model.json", cwd=tmp_path)
    assert "wrote model.json" in proc.stdout
    model = hbjax.load_model(tmp_path / "model.json")
    truth = hbjax.normalise(system, design.h_m)
    np.testing.assert_allclose(hbjax.flatten_params(model), hbjax.flatten_params(truth), atol=0.05)
    shown = run("show", "model.json", cwd=tmp_path).stdout
    assert "Hammerstein" in shown and "c1" in shown


def test_simulate_without_noise_matches_library_exactly(tmp_path, system):
    hbjax.save_model(tmp_path / "m.json", system)
    v = np.sin(np.linspace(0, 20, 200)) * 5
    (tmp_path / "in.csv").write_text("time,drive\n" + "".join(f"{i},{float(x)!r}\n" for i, x in enumerate(v)))
    run("simulate", "--model", "m.json", "--input", "in.csv", "--column", "drive", "--out", "y.csv",
        cwd=tmp_path)
    rec = hbjax.load_recording(tmp_path / "y.csv", input="v", output="y")
    np.testing.assert_array_equal(rec.v, v)
    np.testing.assert_array_equal(rec.y, np.asarray(hbjax.simulate(system, v)))


def test_simulate_keeps_the_input_files_sampling_period(tmp_path, system):
    hbjax.save_model(tmp_path / "m.json", system)
    v = np.sin(np.linspace(0, 20, 200)) * 5
    hbjax.save_recording(tmp_path / "in.csv", hbjax.Recording(v, np.zeros_like(v), dt=0.05))
    assert main(["simulate", "--model", str(tmp_path / "m.json"), "--input",
                 str(tmp_path / "in.csv"), "--out", str(tmp_path / "y.csv")]) == 0
    rec = hbjax.load_recording(tmp_path / "y.csv")
    assert rec.dt == 0.05
    np.testing.assert_array_equal(rec.y, np.asarray(hbjax.simulate(system, v)))


def test_errors_are_one_line_and_nonzero(tmp_path, system):
    hbjax.save_model(tmp_path / "m.json", system)
    (tmp_path / "bad.csv").write_text("v\n1.0\nabc\n")
    proc = run("simulate", "--model", "m.json", "--input", "bad.csv", "--out", "y.csv",
               cwd=tmp_path, check=False)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("hbjax simulate: error:") and "row 3" in lines[0]
    assert not (tmp_path / "y.csv").exists()
    proc = run("--debug", "simulate", "--model", "m.json", "--input", "bad.csv", "--out", "y.csv",
               cwd=tmp_path, check=False)
    assert proc.returncode != 0 and "Traceback" in proc.stderr


def test_no_clobber_without_force(tmp_path, system):
    hbjax.save_model(tmp_path / "m.json", system)
    (tmp_path / "v.csv").write_text("v\n1\n2\n3\n")
    (tmp_path / "y.csv").write_text("keep me\n")
    proc = run("simulate", "--model", "m.json", "--input", "v.csv", "--out", "y.csv",
               cwd=tmp_path, check=False)
    assert proc.returncode == 1 and "--force" in proc.stderr
    assert (tmp_path / "y.csv").read_text() == "keep me\n"
    run("simulate", "--model", "m.json", "--input", "v.csv", "--out", "y.csv", "--force",
        cwd=tmp_path)
    assert len(hbjax.load_recording(tmp_path / "y.csv")) == 3


def _subcommands(parser, prefix=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + (name,), sub
                yield from _subcommands(sub, prefix + (name,))


def test_every_command_has_help_with_an_example(capsys):
    commands = list(_subcommands(build_parser()))
    assert {c[0] for c, _ in commands} >= {"demo", "simulate", "identify", "signals"}
    for command, _ in commands:
        with pytest.raises(SystemExit) as info:
            main([*command, "--help"])
        assert info.value.code == 0
        out = capsys.readouterr().out
        assert re.search(r"examples?:\s+hbjax " + command[0], out), command


def test_usage_error_exits_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["identify", "giri", "--design", "n=2,m=3,h_m=4", "only_one.csv", "--out", "m.json"])
    assert info.value.code == 2


def test_bad_design_is_a_clear_error(tmp_path, capsys):
    for text in ("n=2,m=3", "n=2;m=3;h_m=4", "n=2,m=3,h_m=-1"):
        assert main(["signals", "--design", text, "--samples", "10", "--prefix",
                     str(tmp_path / "v")]) == 1
        err = capsys.readouterr().err
        assert err.startswith("hbjax signals: error: --design") and err.count("\n") == 1


def test_design_with_a_repeated_key_is_refused(tmp_path, capsys):
    # A later value used to win silently: n=3 here, not the n=2 the user may have read.
    assert main(["signals", "--design", "n=2,m=3,h_m=4,n=3", "--samples", "20", "--prefix",
                 str(tmp_path / "v")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--design gives 'n' twice" in err
    assert not list(tmp_path.iterdir())


def _giri_records(tmp_path, system, h_m, samples=200):
    """The three experiments of design n=2, m=3, ``h_m``, saved as `hbjax simulate` does
    (columns v, y); returns the file names."""
    design = hbjax.GiriDesign(2, 3, h_m)
    names = []
    for k, v in enumerate((design.constant_input(samples), design.binary_input(samples),
                           design.staircase_input(samples)), 1):
        y = np.asarray(hbjax.simulate(system, v))
        hbjax.save_recording(tmp_path / f"y{k}.csv", hbjax.Recording(v, y))
        names.append(str(tmp_path / f"y{k}.csv"))
    return names


def test_identify_giri_checks_the_recorded_inputs(tmp_path, system, capsys):
    # Recorded with h_m = 4, identified as h_m = 8: the v column says so.
    records = _giri_records(tmp_path, system, 4.0)
    out = tmp_path / "m.json"
    assert main(["identify", "giri", "--design", "n=2,m=3,h_m=8", *records, "--out",
                 str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("hbjax identify giri: error: `v1`")
    assert "y1.csv" in err and "--design" in err and not out.exists()
    assert main(["identify", "giri", "--design", "n=2,m=3,h_m=4", *records, "--out",
                 str(out)]) == 0
    np.testing.assert_allclose(hbjax.flatten_params(hbjax.load_model(out)),
                               hbjax.flatten_params(hbjax.normalise(system, 4.0)), atol=1e-6)
    # An input column named as the output column is a slip, not a recorded input.
    assert main(["identify", "giri", "--design", "n=2,m=3,h_m=4", *records, "--input", "y",
                 "--out", str(tmp_path / "m2.json")]) == 1
    assert "--input and --output name the same column" in capsys.readouterr().err
    # Output-only files (one column) have nothing to check and still work.
    for path in records:
        y = hbjax.load_recording(path).y
        pathlib.Path(path).write_text("y\n" + "".join(f"{float(x)!r}\n" for x in y))
    assert main(["identify", "giri", "--design", "n=2,m=3,h_m=4", *records, "--out",
                 str(tmp_path / "m3.json")]) == 0


def test_console_script_is_installed():
    script = pathlib.Path(sys.executable).parent / "hbjax"
    if not script.exists():
        pytest.skip("package not installed with its console script")
    proc = subprocess.run([str(script), "--help"], capture_output=True, text=True, env=ENV, timeout=120)
    assert proc.returncode == 0 and "simulate" in proc.stdout


def test_montecarlo_writes_statistics_and_figure(tmp_path, system, design):
    config = {"model": "default", "design": "n=2,m=3,h_m=4", "noise_std": 0.2,
              "lengths": [180, 360], "realisations": 4, "seed": 3}
    (tmp_path / "cfg.json").write_text(json.dumps(config))
    proc = run("montecarlo", "--config", "cfg.json", "--out", "study.json", "--plot", "study.png",
               "--no-progress", cwd=tmp_path)
    assert "log-log RMSE slope" in proc.stdout and "wrote study.json" in proc.stdout
    doc = json.loads((tmp_path / "study.json").read_text())
    assert doc["format"] == "hbjax-study" and doc["config"] == config
    study = doc["study"]
    assert study["lengths"] == [180, 360] and study["n_valid"] == [4, 4]
    truth = hbjax.flatten_params(hbjax.normalise(system, design.h_m))
    np.testing.assert_array_equal(study["true"], np.asarray(truth))
    assert np.asarray(study["rmse"]).shape == (2, len(study["names"]))
    assert study["estimates"] is None
    assert (tmp_path / "study.png").read_bytes()[:4] == b"\x89PNG"


def test_montecarlo_config_errors(tmp_path):
    (tmp_path / "cfg.json").write_text('{"noise_std": 0.1, "lengths": [100], "realisation": 3}')
    proc = run("montecarlo", "--config", "cfg.json", "--out", "s.json", cwd=tmp_path, check=False)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert "unknown config keys ['realisation']" in proc.stderr
    proc = run("montecarlo", "--config", "cfg.json", "--out", "cfg.json", cwd=tmp_path, check=False)
    assert proc.returncode == 1 and "would replace the config file" in proc.stderr
    (tmp_path / "cfg.json").write_text(
        '{"noise_std": 0.1, "lengths": [100], "realisations": 2, "seed": %d}' % 10**23)
    proc = run("montecarlo", "--config", "cfg.json", "--out", "s.json", cwd=tmp_path, check=False)
    assert proc.returncode == 1 and "`seed` must be in [0, 2**63)" in proc.stderr


@pytest.mark.parametrize("seed", ["99999999999999999999", "-1", "1.5"])
def test_seed_option_is_checked_by_name(tmp_path, seed):
    proc = run("simulate", "--model", "m.json", "--input", "v.csv", "--out", "y.csv",
               "--seed", seed, cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "argument --seed: must be" in proc.stderr


@pytest.mark.slow
def test_diagnose_reports_and_saves_the_extended_model(tmp_path, system):
    from hbjax._diagnose.effects import OutputSaturation

    rng = np.random.default_rng(0)
    v = np.repeat(rng.uniform(-6, 6, 100), 8)
    truth = OutputSaturation(system, None, jnp.asarray(12.0))
    y = hbjax.simulate(truth, v, 0.1 * rng.standard_normal(v.size))
    # a recorded channel that explains nothing (a sensor's own noise): offered, not named
    hbjax.save_recording(tmp_path / "rec.csv", hbjax.Recording(
        v, np.asarray(y), dt=1.0, channels={"probe": rng.standard_normal(v.size)}))
    hbjax.save_model(tmp_path / "nominal.json", system)
    proc = run("diagnose", "--model", "nominal.json", "rec.csv", "--input", "v",
               "--output", "y", "--effects", "output_saturation", "--json", "report.json",
               "--plot", "report.png", "--save-model", "best.json", cwd=tmp_path)
    assert "channels offered: probe" in proc.stdout
    assert "1. output_saturation" in proc.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["format"] == "hbjax-diagnosis" and report["report"]["best"] == "output_saturation"
    best = hbjax.load_model(tmp_path / "best.json")
    assert isinstance(best, OutputSaturation) and best.lower is None
    assert abs(float(best.upper) - 12.0) < 0.1
    assert (tmp_path / "report.png").read_bytes()[:4] == b"\x89PNG"
    shown = run("show", "best.json", cwd=tmp_path).stdout
    assert "OutputSaturation" in shown and "upper" in shown


def test_identify_fit_on_ordinary_recordings(tmp_path, system):
    rng = np.random.default_rng(1)
    records = []
    for k in range(2):
        v = np.repeat(rng.uniform(-6, 6, 50), 6)
        y = np.asarray(hbjax.simulate(system, v, 0.05 * rng.standard_normal(v.size)))
        hbjax.save_recording(tmp_path / f"r{k}.csv", hbjax.Recording(v, y, dt=0.5))
        records.append(f"r{k}.csv")
    # Columns by header name: save_recording writes t, v, y when dt is known.
    proc = run("identify", "fit", "--na", 2, "--nb", 2, "--m", 3, *records, "--input", "v",
               "--output", "y", "--starts", 8, "--out", "fit.json", cwd=tmp_path)
    assert "2 recording(s), 600 samples" in proc.stdout
    # Standard errors print with significant digits: a small one is never shown as 0.
    line = next(x for x in proc.stdout.splitlines() if "standard errors" in x)
    shown = np.array([float(x) for x in line.split("=", 1)[1].strip(" []").split(",")])
    assert shown.size == 10 and np.all(shown > 0)
    model = hbjax.load_model(tmp_path / "fit.json")
    np.testing.assert_allclose(hbjax.flatten_params(model),
                               hbjax.flatten_params(hbjax.normalise_static_gain(system)), atol=0.05)
    assert "criterion: simulation" in proc.stdout  # the command's default
    # hbjax.fit's default: equation noise leaves the one-step errors white
    proc = run("identify", "fit", "--na", 2, "--nb", 2, "--m", 3, *records, "--input", "v",
               "--output", "y", "--starts", 8, "--criterion", "auto", "--out", "auto.json",
               cwd=tmp_path)
    assert "criterion: auto: prediction (its one-step errors are white)" in proc.stdout


def test_identify_fit_loop_tolerance_is_checked_as_typed(tmp_path, system):
    v = np.repeat(np.random.default_rng(2).uniform(-6, 6, 50), 6)
    hbjax.save_recording(tmp_path / "r.csv", hbjax.Recording(v, np.asarray(hbjax.simulate(system, v))))
    proc = run("identify", "fit", "--na", 2, "--nb", 2, "--m", 3, "r.csv", "--loop-tolerance", 0,
               "--out", "fit.json", cwd=tmp_path, check=False)
    assert proc.returncode == 1, proc.stderr
    assert "`--loop-tolerance` must be a positive number" in proc.stderr
    assert not (tmp_path / "fit.json").exists()
