"""Files and the command line under adversarial use: round trips of what hbjax writes,
special files, races, long names, hostile model files, output checks before any work,
Ctrl-C, and property tests of the readers and writers."""

import contextlib
import errno
import io
import json
import os
import pathlib
import runpy
import signal
import stat
import subprocess
import sys
import warnings

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hbjax


M = hbjax.default_system()
FS = settings(max_examples=50, deadline=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture])
DOCUMENTED = (hbjax.ModelFileError, ValueError, FileNotFoundError, IsADirectoryError)


def cli(*argv, monkeypatch=None):
    """(status, stdout, stderr) of ``python -m hbjax ARGV`` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    saved = sys.argv
    sys.argv = ["hbjax", *map(str, argv)]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                runpy.run_module("hbjax", run_name="__main__", alter_sys=False)
                status = 0
            except SystemExit as exc:
                status = exc.code
    finally:
        sys.argv = saved
    return status, out.getvalue(), err.getvalue()


def same_recording(a, b):
    assert a.v.tobytes() == b.v.tobytes() and a.y.tobytes() == b.y.tobytes()
    assert a.dt == b.dt and a.t0 == b.t0
    assert list(a.channels) == list(b.channels)
    assert all(a.channels[k].tobytes() == b.channels[k].tobytes() for k in a.channels)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", ["csv", "npz"])
def test_saved_recording_reads_back_unshifted(tmp_path, suffix):
    rec = hbjax.Recording([1.0, 2, 3], [10.0, 20, 30], dt=0.5)
    back = hbjax.load_recording(hbjax.save_recording(tmp_path / f"r.{suffix}", rec))
    same_recording(rec, back)
    np.testing.assert_array_equal(back.v, [1.0, 2, 3])


def test_bundled_record_saved_and_read_by_the_cli(tmp_path):
    est, _ = hbjax.datasets.cascaded_tanks()
    p = hbjax.save_recording(tmp_path / "tanks.csv", est)
    same_recording(est, hbjax.load_recording(p))
    # The command line picks the columns v and y of the layout hbjax writes (not t, v).
    status, _, err = cli("simulate", "--model", hbjax.save_model(tmp_path / "m.json", M),
                         "--input", p, "--out", tmp_path / "y.csv")
    assert status == 0, err
    assert hbjax.load_recording(tmp_path / "y.csv").v.tobytes() == est.v.tobytes()


def test_sampling_period_and_length_one_round_trip(tmp_path):
    rec = hbjax.Recording(np.zeros(100_000), np.ones(100_000), dt=0.1)
    p = hbjax.save_recording(tmp_path / "long.csv", rec)
    assert hbjax.load_recording(p).dt == 0.1
    assert hbjax.load_recording(p, time="t").dt == 0.1
    one = hbjax.Recording([1.0], [2.0], dt=0.1, t0=3.3)
    p = hbjax.save_recording(tmp_path / "one.csv", one)
    same_recording(one, hbjax.load_recording(p, time="t"))
    # Times 0.1, 0.2, 0.3 written by hand give dt = 0.1, not 0.09999999999999998.
    hand = tmp_path / "hand.csv"
    hand.write_text("time,v,y\n" + "".join(f"{k / 10},{k},{k}\n" for k in range(1, 40)))
    assert hbjax.load_recording(hand, time="time").dt == 0.1


def test_huge_dt_is_refused_not_written_as_inf(tmp_path):
    with pytest.raises(ValueError, match="exceeds the largest float64"):
        hbjax.save_recording(tmp_path / "r.csv", hbjax.Recording([1.0, 2, 3], [1.0, 2, 3], dt=1e308))
    assert not (tmp_path / "r.csv").exists()
    # reading refuses what writing refuses: a file whose times overflow
    np.savez(tmp_path / "huge.npz", v=np.arange(10.0), y=np.arange(10.0), dt=1e308)
    with pytest.raises(ValueError, match="huge.npz: the time of sample 2, t0 . 2 . dt, exceeds the largest"):
        hbjax.load_recording(tmp_path / "huge.npz")
    with pytest.raises(ValueError, match="BRFD layout"):
        hbjax.save_recording(tmp_path / "r.json", hbjax.Recording([1.0], [1.0]))


@pytest.mark.parametrize("cell", ["1_000", "\uff11\uff12", "0x10", "1e", "--1"])
def test_loose_numbers_are_refused(tmp_path, cell):
    p = tmp_path / "r.csv"
    p.write_text(f"v,y\n1,2\n{cell},3\n")
    with pytest.raises(ValueError, match=r"non-numeric cell .* at row 3, column 0"):
        hbjax.load_recording(p)


# ----------------------------------------------------------------------------- special files


def test_special_files_are_written_into_never_replaced(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = subprocess.Popen([sys.executable, "-c", f"print(len(open({str(fifo)!r}).read()))"],
                              stdout=subprocess.PIPE, text=True)
    hbjax.save_recording(fifo, hbjax.Recording([1.0, 2.0], [3.0, 4.0]))
    assert int(reader.communicate(timeout=60)[0]) > 0
    assert pathlib.Path(fifo).is_fifo()
    for target in ("/dev/null", fifo):
        link = tmp_path / f"link{len(str(target))}"
        link.symlink_to(target)
        if target == "/dev/null":
            hbjax.save_model(link, M, overwrite=True)
            hbjax.save_model("/dev/null", M)  # a device is written into: no overwrite needed
            assert os.path.islink(link) and pathlib.Path("/dev/null").is_char_device()
    with pytest.raises(ValueError, match="standard output"):
        hbjax.save_model("-", M)
    # A symbolic link to a regular file stays a link; the file behind it is replaced.
    real = tmp_path / "real.json"
    real.write_text("old")
    (tmp_path / "alias.json").symlink_to(real)
    hbjax.save_model(tmp_path / "alias.json", M, overwrite=True)
    assert os.path.islink(tmp_path / "alias.json") and hbjax.load_model(real) is not None


@pytest.mark.skipif(not pathlib.Path("/proc/self/fd").is_dir(), reason="needs /proc")
def test_redirected_stdout_is_written_into_other_proc_names_are_not(tmp_path, monkeypatch):
    # `--out /dev/stdout` with standard output redirected to a file appends to that file,
    # also through /dev/fd/1 and /proc/self/fd/1: these name an open file.
    hbjax.save_model(tmp_path / "m.json", M)
    hbjax.save_recording(tmp_path / "v.csv", hbjax.Recording([1.0, 2.0], [0.0, 0.0]))
    out = tmp_path / "out.txt"
    out.write_text("before\n")
    for name in ("/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"):
        with open(out, "ab") as fh:
            proc = subprocess.run([sys.executable, "-m", "hbjax", "simulate", "--model", "m.json",
                                   "--input", "v.csv", "--out", name], cwd=tmp_path,
                                  stdout=fh, stderr=subprocess.PIPE, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert text.startswith("before\n") and text.count("v,y") == 3
    # A regular file reached through /proc/self/cwd or /proc/self/root is an ordinary file:
    # kept without overwrite, replaced with it (it used to be appended to).
    monkeypatch.chdir(tmp_path)
    user = tmp_path / "user.json"
    for name in ("/proc/self/cwd/user.json", f"/proc/self/root{user}"):
        user.write_text("precious\n")
        with pytest.raises(FileExistsError, match="already exists"):
            hbjax.save_model(name, M)
        assert user.read_text() == "precious\n"
        hbjax.save_model(name, M, overwrite=True)
        assert type(hbjax.load_model(user)) is hbjax.Hammerstein
    hbjax.save_model("/proc/self/cwd/new.json", M)
    assert type(hbjax.load_model(tmp_path / "new.json")) is hbjax.Hammerstein


def test_no_hard_links_falls_back_without_clobbering(tmp_path, monkeypatch):
    target = tmp_path / "r.csv"

    def link_fails_and_file_appears(src, dst):
        pathlib.Path(dst).write_text("someone else's data")  # appears during the write
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", link_fails_and_file_appears)
    with pytest.raises(FileExistsError, match="already exists"):
        hbjax.save_recording(target, hbjax.Recording([1.0], [2.0]))
    assert target.read_text() == "someone else's data"
    monkeypatch.setattr(os, "link", lambda src, dst: (_ for _ in ()).throw(
        OSError(errno.EOPNOTSUPP, "not supported")))
    new = hbjax.save_recording(tmp_path / "new.csv", hbjax.Recording([1.0], [2.0]))
    assert hbjax.load_recording(new).y.tolist() == [2.0]
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


@pytest.mark.parametrize("length", [245, 250, 255])
def test_long_file_names(tmp_path, length):
    p = tmp_path / ("m" * (length - 5) + ".json")
    hbjax.save_model(p, M)
    assert type(hbjax.load_model(p)) is hbjax.Hammerstein


# ----------------------------------------------------------------------------- model files


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o444])
def test_overwrite_keeps_the_files_permissions(tmp_path, mode):
    """A private (or read-only) file replaced with ``overwrite=True`` keeps its mode; it
    came back world-readable 0644 (the temporary file's umask default)."""
    p = hbjax.save_model(tmp_path / "m.json", M)
    os.chmod(p, mode)
    hbjax.save_model(p, M, overwrite=True)
    assert stat.S_IMODE(os.stat(p).st_mode) == mode
    rec = hbjax.Recording(v=np.arange(5.0), y=np.arange(5.0))
    r = hbjax.save_recording(tmp_path / "r.csv", rec)
    os.chmod(r, mode)
    hbjax.save_recording(r, rec, overwrite=True)
    assert stat.S_IMODE(os.stat(r).st_mode) == mode


@pytest.mark.parametrize("suffix", ["csv", "npz"])
@pytest.mark.parametrize("columns", [{"input": "y", "output": "y"}, {"input": 0, "output": "v"},
                                     {"input": "y"}])
def test_one_column_is_never_both_input_and_output(tmp_path, suffix, columns):
    rec = hbjax.Recording(v=np.arange(5.0), y=np.arange(5.0) ** 2)
    p = hbjax.save_recording(tmp_path / f"r.{suffix}", rec)
    with pytest.raises(ValueError, match="the input and the output are the same column"):
        hbjax.load_recording(p, **columns)


def test_cli_refuses_one_column_as_input_and_output(tmp_path):
    p = hbjax.save_recording(tmp_path / "r.csv", hbjax.Recording(v=np.arange(50.0),
                                                                 y=np.sin(np.arange(50.0))))
    status, out, err = cli("identify", "fit", "--input", "y", "--output", "y", p,
                           "--out", tmp_path / "m.json")
    assert status != 0 and "same column" in err and not (tmp_path / "m.json").exists()


def test_model_file_cannot_name_hbjax_main_or_any_module(tmp_path):
    text = hbjax.save_model(tmp_path / "m.json", M).read_text()
    before = set(sys.modules)
    for name in ("hbjax.__main__.X", "hbjax._cli.parser.main", "os.system", "hbjax.Hammerstein"):
        p = tmp_path / "evil.json"
        p.write_text(text.replace('"class": "Hammerstein"', f'"class": "{name}"', 1))
        with pytest.raises(hbjax.ModelFileError, match="unknown model class"):
            hbjax.load_model(p)
    assert set(sys.modules) - before == set()


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda t: t.replace('"format_version": 1', '"format_version": 1' + "0" * 5000), "not a valid JSON"),
        (lambda t: t.replace('"format_version": 1', '"format_version": ' + "[" * 50000 + "]" * 50000), "nested too deeply|not a valid JSON"),
        (lambda t: t.replace('"dtype": "float64"', '"dtype": "int64"', 1).replace("[-1.2", "[" + "9" * 400, 1), "too large|must hold|integers"),
        (lambda t: json.dumps({"format": "hbjax-model", "format_version": 1, "kind": "Backlash", "model": {"class": "Backlash", "fields": {"c1": {"array": [], "dtype": "float64", "shape": [9_000_000]}, "c2": {"array": [], "dtype": "float64", "shape": [9_000_000]}}}}), "at most m = 64"),
        (lambda t: t.replace('"format_version": 1', '"format_version": NaN'), "not a valid JSON"),
    ],
)
def test_hostile_model_files_give_model_file_errors(tmp_path, edit, match):
    text = hbjax.save_model(tmp_path / "m.json", M).read_text()
    p = tmp_path / "bad.json"
    p.write_text(edit(text))
    with pytest.raises(hbjax.ModelFileError, match=match):
        hbjax.load_model(p)


SCALAR = {"array": [5.0], "dtype": "float64", "shape": [], "kind": "jax"}


@pytest.mark.parametrize(
    "effect, field, value, match",
    [
        ("output_saturation", "upper", "abc", r"OutputSaturation\.upper` must be a numeric"),
        ("output_saturation", "upper", {"float": "nan"}, r"upper` must be finite"),
        ("output_saturation", "upper", {"array": [1.0, 2.0, 3.0], "dtype": "float64",
                                        "shape": [3]}, r"upper` must be a scalar"),
        ("output_saturation", "upper", True, r"upper` must be numeric"),
        ("output_saturation", "lower", SCALAR, r"lower` \(5\.0\) must be below"),
        ("extra_delay", "delay", 2.5, r"ExtraDelay\.delay` must be an integer"),
        ("extra_delay", "delay", 99, r"ExtraDelay\.delay` must be in \[0, 12\]"),
    ],
)
def test_effect_files_with_invalid_parameters_give_model_file_errors(
        tmp_path, effect, field, value, match):
    cls = hbjax.EFFECTS[effect]
    model = cls(M, None, 3.0) if effect == "output_saturation" else cls(M, 2)
    doc = json.loads(hbjax.save_model(tmp_path / "e.json", model).read_text())
    doc["model"]["fields"][field] = value
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(hbjax.ModelFileError, match=rf"`model` \({cls.__name__}\).*{match}"):
        hbjax.load_model(p)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("lower", "abc", r"`LevelCascade.lower` must be a numeric array, got str"),
        ("lower", {"list": [1, 2]}, r"`LevelCascade.lower` must be a scalar, got shape \(2,\)"),
        ("upper", {"float": "nan"}, r"`LevelCascade.upper` must be finite or None, got nan"),
        ("lower", 5.0, r"needs `LevelCascade.lower` < `LevelCascade.upper`, got 5.0 and -5.0"),
        ("y_center", "abc", r"`LevelCascade.y_center` must be a numeric array"),
        ("y_center", {"float": "inf"}, r"`LevelCascade.y_center` must be finite"),
        ("w_scale", "abc", r"`LevelCascade.w_scale` must be a numeric array"),
        ("w_scale", 0.0, r"`LevelCascade.w_scale` must be > 0, got 0.0"),
        ("params", {"array": [0.1] * 8 + [{"float": "nan"}], "dtype": "float64", "shape": [9],
                    "kind": "jax"}, r"`LevelCascade.params` must be finite"),
    ],
)
def test_level_cascade_files_with_invalid_values_give_model_file_errors(
        tmp_path, field, value, match):
    """The diagnosis's two-store model is held to its constructor's checks when read back,
    as the effects are: an edited file fails on loading, not later inside a simulation."""
    from hbjax._diagnose.level_cascade import LevelCascade

    model = LevelCascade(M, np.full(9, 0.1), np.zeros(2), 1.0, 0.0, 1.0, -5.0, 5.0)
    doc = json.loads(hbjax.save_model(tmp_path / "c.json", model).read_text())
    doc["model"]["fields"][field] = value
    if field == "lower":
        doc["model"]["fields"]["upper"] = -5.0 if value == 5.0 else doc["model"]["fields"]["upper"]
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(hbjax.ModelFileError, match=rf"`model` \(LevelCascade\).*{match}"):
        hbjax.load_model(p)
    assert isinstance(hbjax.load_model(tmp_path / "c.json"), LevelCascade)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("base", "hello", r"MissingInput\.base` must be an hbjax\.Hammerstein, got str"),
        ("scale", {"array": [0.0], "dtype": "float64", "shape": [1]},
         r"MissingInput\.scale` must be > 0"),
        ("gain", {"float": "inf"}, r"MissingInput\.gain` must be finite"),
        ("taps", {"array": [0.0] * 6, "dtype": "float64", "shape": [2, 3]},
         r"MissingInput\.taps` must have shape \(1, 4\)"),
        ("channel_names", 5, r"MissingInput\.channel_names` must be a non-empty tuple"),
    ],
)
def test_missing_input_files_are_held_to_their_fields(tmp_path, field, value, match):
    """The diagnosis's recorded-channel extension, as ``diagnose --save-model`` writes it:
    an edited file is refused naming the field (it used to load and fail, or run, later)."""
    from hbjax._diagnose.channels import MissingInput

    n = 20
    model = MissingInput(M, np.arange(n, dtype=float)[:, None], np.zeros(1), np.ones(1),
                         np.zeros((1, 4)), np.zeros(1), np.asarray(0.0), np.asarray(0.0), ("w",))
    doc = json.loads(hbjax.save_model(tmp_path / "mi.json", model).read_text())
    doc["model"]["fields"][field] = value
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(hbjax.ModelFileError, match=match):
        hbjax.load_model(p)
    assert hbjax.load_model(tmp_path / "mi.json").channel_names == ("w",)


def test_missing_input_model_runs_only_on_its_record():
    """The channels of ``missing_input`` were recorded with one record: the model runs on
    it or a prefix of it (the prefix's output equals the record's first samples), and a
    longer input is refused naming `v`, by simulate, predict and compare, rather than
    holding the last recorded value."""
    from hbjax._diagnose.channels import MissingInput

    n = 40
    rng = np.random.default_rng(3)
    model = MissingInput(M, rng.standard_normal((n, 1)), np.zeros(1), np.ones(1),
                         0.1 * np.ones((1, 4)), np.zeros(1), np.asarray(0.0), np.asarray(0.0),
                         ("w",))
    assert model.record_length() == n and M.record_length() is None
    v = np.sin(np.arange(n + 5) / 3.0)
    full = np.asarray(hbjax.simulate(model, v[:n]))
    np.testing.assert_allclose(np.asarray(hbjax.simulate(model, v[:25])), full[:25], atol=1e-12)
    y = full + 0.01 * rng.standard_normal(n)
    for call in (lambda: hbjax.simulate(model, v), lambda: hbjax.predict(model, v, np.r_[y, y[:5]]),
                 lambda: hbjax.compare(model, v, np.r_[y, y[:5]], initial_state="zero")):
        with pytest.raises(ValueError, match=r"`v` has 45 samples.*recorded with 40"):
            call()


def test_polynomial_degree_is_capped_and_evaluated_exactly():
    with pytest.raises(ValueError, match="at most m = 64"):
        hbjax.Backlash(np.ones(65), np.ones(65))
    rng = np.random.default_rng(0)
    c = rng.normal(size=64) / np.arange(1, 65) ** 2
    bl = hbjax.Backlash(c, c + 1.0)
    v = np.linspace(-1.1, 1.1, 301)
    ref = np.full_like(v, c[-1])
    for k in range(62, -1, -1):
        ref = ref * v + c[k]
    np.testing.assert_allclose(np.asarray(bl.p1(v)), ref, rtol=0, atol=1e-13)


def test_clear_errors_for_directories_npz_and_brfd_json(tmp_path):
    with pytest.raises(IsADirectoryError, match="is a directory"):
        hbjax.load_recording(tmp_path)
    with pytest.raises(IsADirectoryError, match="is a directory"):
        hbjax.load_model(tmp_path)
    np.savez(tmp_path / "r.npz", v=np.ones(3), y=np.ones(3), dt=np.ones(2))
    with pytest.raises(ValueError, match="'dt' must hold one real number"):
        hbjax.load_recording(tmp_path / "r.npz")
    np.savez(tmp_path / "c.npz", v=np.ones(3) + 1j, y=np.ones(3))
    with pytest.raises(ValueError, match="must be real"):
        hbjax.load_recording(tmp_path / "c.npz")
    for body, match in [('{"data": [[0, 1, 1%s]]}' % ("0" * 400), "too large for a float64"),
                        ('{"data": [[0, 1, 1%s]]}' % ("0" * 5000), "not valid JSON"),
                        ("[" * 100_000, "not valid JSON")]:
        (tmp_path / "b.json").write_text(body)
        with pytest.raises(ValueError, match=match):
            hbjax.load_recording(tmp_path / "b.json")


def test_normalise_blames_h_m_for_inf():
    with pytest.raises(ValueError, match="`h_m`"):
        hbjax.normalise(M, np.inf)


# ----------------------------------------------------------------------------- the command line


def test_outputs_are_checked_before_any_work_and_written_together(tmp_path):
    model = hbjax.save_model(tmp_path / "m.json", M)
    rec = hbjax.save_recording(tmp_path / "r.csv", hbjax.Recording(np.linspace(-3, 3, 40), np.zeros(40)))
    config = tmp_path / "c.json"
    config.write_text('{"noise_std": 0.1, "lengths": [40], "realisations": 2}')
    cases = [
        (("diagnose", "--model", model, rec, "--json", tmp_path / "X", "--save-model", tmp_path / "X"), "--json and --save-model name the same file"),
        (("montecarlo", "--config", config, "--out", tmp_path / "s.json", "--plot", tmp_path / "s.bmpx"), "unsupported figure format 'bmpx'"),
        (("montecarlo", "--config", config, "--out", tmp_path / "s.json", "--plot", tmp_path / "s.json"), "name the same file"),
        (("montecarlo", "--config", config, "--out", config), "would replace the config file"),
        (("identify", "fit", "--na", 1, "--nb", 1, "--m", 2, rec, "--out", rec, "--force"), "would replace the input file"),
        (("simulate", "--model", model, "--input", rec, "--out", "-"), "standard output"),
    ]
    for argv, match in cases:
        status, out, err = cli(*argv)
        assert status == 1 and match in err, (argv, err)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "m.json", "r.csv"], argv
    (tmp_path / "v2.csv").write_text("keep")
    status, _, err = cli("signals", "--design", "n=2,m=3,h_m=4", "--samples", 40, "--prefix", tmp_path / "v")
    assert status == 1 and "v2.csv' already exists" in err
    assert not (tmp_path / "v1.csv").exists() and (tmp_path / "v2.csv").read_text() == "keep"


def test_cli_errors_name_the_subcommand_and_options_as_typed(tmp_path):
    rec = hbjax.save_recording(tmp_path / "r.csv", hbjax.Recording(np.linspace(-3, 3, 40), np.zeros(40)))
    status, _, err = cli("identify", "fit", "--na", 2, "--nb", 2, "--m", 0, rec, "--out", tmp_path / "f.json")
    assert status == 1 and err.startswith("hbjax identify fit: error:") and "`--m`" in err
    status, _, err = cli("simulate", "--model", hbjax.save_model(tmp_path / "m.json", M), "--input", rec,
                         "--out", tmp_path / "y.csv", "--noise-std", "nan")
    assert status == 1 and "--noise-std must be a finite number" in err
    config = tmp_path / "c.json"
    config.write_text('{"noise_std": 0.1, "lengths": [40], "realisations": 2, "keep_estimates": "false"}')
    status, _, err = cli("montecarlo", "--config", config, "--out", tmp_path / "s.json", "--no-progress")
    assert status == 1 and "`keep_estimates` must be true or false" in err


def _cpu_seconds(pid: int) -> float:
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.skipif(not pathlib.Path("/proc/self/stat").exists(), reason="needs /proc")
def test_ctrl_c_during_a_study_exits_130_cleanly(tmp_path):
    config = tmp_path / "c.json"
    config.write_text('{"noise_std": 0.5, "lengths": [2000], "realisations": 200000}')
    # The command's Ctrl-C handler is installed once `import hbjax` has run; a Ctrl-C
    # during that import is Python's own (a traceback), so the stages are counted from the
    # import's CPU time on this machine (a fresh clone's first import also writes the
    # bytecode caches: seen taking over 3 s on a loaded machine).
    imported = subprocess.run([sys.executable, "-c", "import time, hbjax; print(time.process_time())"],
                              capture_output=True, text=True, check=True, cwd=tmp_path)
    start = float(imported.stdout.split()[-1])
    outcomes, messages = [], []
    for cpu in (start + 1.5, start + 4.5, start + 7.5):  # set-up, compiling, running
        proc = subprocess.Popen([sys.executable, "-m", "hbjax", "montecarlo", "--config", config,
                                 "--out", tmp_path / "s.json"], stderr=subprocess.PIPE,
                                stdout=subprocess.DEVNULL, cwd=tmp_path)
        while proc.poll() is None and _cpu_seconds(proc.pid) < cpu:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=0.1)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
        outcomes.append((proc.returncode, b"interrupted" in err))
        messages.append(err.decode(errors="replace")[-400:])
    assert outcomes == [(130, True)] * 3, messages
    assert not (tmp_path / "s.json").exists()


_SWALLOWED_CTRL_C = """
import gc, os, signal, sys, time
from hbjax._cli import parser

parser._watch_interrupts("hbjax demo")

def collect(phase, info):  # the Ctrl-C arrives inside a garbage-collection callback
    if phase == "start" and not getattr(collect, "done", False):
        collect.done = True
        os.kill(os.getpid(), signal.SIGINT)

gc.callbacks.append(collect)
gc.collect()
t0 = time.monotonic()
while time.monotonic() - t0 < 60:  # the command runs on: only the watchdog can end it
    time.sleep(0.05)
sys.exit(0)
"""


def test_ctrl_c_swallowed_by_a_callback_still_ends_the_command_with_130():
    proc = subprocess.run([sys.executable, "-c", _SWALLOWED_CTRL_C], capture_output=True,
                          timeout=120)
    err = proc.stderr.decode(errors="replace")
    assert "Exception ignored" in err  # Python did swallow the KeyboardInterrupt
    # (the script itself would exit 0 after its minute)
    assert proc.returncode == 130 and "hbjax demo: interrupted" in err, err


# ----------------------------------------------------------------------------- properties

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@FS
@given(v=st.lists(finite, min_size=1, max_size=30), data=st.data(),
       dt=st.one_of(st.none(), st.floats(min_value=1e-300, max_value=1e10)),
       t0=st.floats(-1e6, 1e6), suffix=st.sampled_from(["csv", "npz"]))
def test_any_recording_written_reads_back_bit_for_bit(tmp_path, v, data, dt, t0, suffix):
    y = data.draw(st.lists(finite, min_size=len(v), max_size=len(v)))
    chan = data.draw(st.lists(finite, min_size=len(v), max_size=len(v)))
    rec = hbjax.Recording(v, y, dt=dt, t0=t0, channels={"force 2": chan})
    p = hbjax.save_recording(tmp_path / f"r.{suffix}", rec, overwrite=True)
    same_recording(rec, hbjax.load_recording(p))
    if dt is not None and suffix == "csv":
        same_recording(rec, hbjax.load_recording(p, time="t"))


@FS
@given(c=st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=8),
       a=st.lists(st.floats(-0.9, 0.9), min_size=0, max_size=4),
       b=st.lists(finite, min_size=1, max_size=4))
def test_any_model_written_reads_back_bit_for_bit(tmp_path, c, a, b):
    model = hbjax.Hammerstein(hbjax.Backlash(c, [x + 1.0 for x in c]), hbjax.ARX(a, b))
    back = hbjax.load_model(hbjax.save_model(tmp_path / "m.json", model, overwrite=True))
    for x, z in zip(jax.tree_util.tree_leaves(model), jax.tree_util.tree_leaves(back)):
        assert np.asarray(x).tobytes() == np.asarray(z).tobytes()


def _sample_files(tmp):
    rec = hbjax.Recording(np.linspace(-1, 1, 8), np.arange(8.0), dt=0.25, channels={"c": np.ones(8)})
    return {"csv": hbjax.save_recording(tmp / "s.csv", rec, overwrite=True).read_bytes(),
            "npz": hbjax.save_recording(tmp / "s.npz", rec, overwrite=True).read_bytes(),
            "json": hbjax.save_model(tmp / "s.json", M, overwrite=True).read_bytes()}


@FS
@given(kind=st.sampled_from(["csv", "npz", "json"]), cut=st.floats(0, 1),
       noise=st.binary(max_size=64), where=st.floats(0, 1), mode=st.sampled_from(["cut", "splice", "random"]))
def test_damaged_files_raise_only_documented_errors(tmp_path, kind, cut, noise, where, mode):
    good = _sample_files(tmp_path)[kind]
    if mode == "cut":
        data = good[: int(cut * len(good))]
    elif mode == "splice":
        i = int(where * len(good))
        data = good[:i] + noise + good[i + len(noise):]
    else:
        data = noise
    p = tmp_path / f"bad.{kind}"
    p.write_bytes(data)
    load = hbjax.load_model if kind == "json" else hbjax.load_recording
    try:
        load(p)
    except DOCUMENTED:
        pass


def test_a_channel_named_twice_in_a_saved_file_is_refused_not_merged(tmp_path):
    rec = hbjax.Recording([1.0, 2, 3], [10.0, 20, 30], dt=0.5,
                          channels={"force": [1.0, 2, 3], "speed": [4.0, 5, 6]})
    p = hbjax.save_recording(tmp_path / "r.csv", rec)
    same_recording(rec, hbjax.load_recording(p))
    text = p.read_text().replace("speed", "force")  # edited by hand
    p.write_text(text)
    with pytest.raises(ValueError, match=r"channel 'force' is named by two header columns"):
        hbjax.load_recording(p)


def test_a_model_file_saved_with_a_byte_order_mark_is_read(tmp_path):
    """Windows editors often save UTF-8 with a byte-order mark; the model reads back the same."""
    path = hbjax.save_model(tmp_path / "m.json", M)
    marked = tmp_path / "bom.json"
    marked.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    back = hbjax.load_model(marked)
    np.testing.assert_array_equal(hbjax.flatten_params(back), hbjax.flatten_params(M))


def test_a_folder_that_takes_no_new_file_is_named_with_the_users_file(tmp_path):
    """Where the temporary file cannot be made (here a folder of /proc), the error names the
    file asked for, not the hidden temporary one."""
    target = pathlib.Path("/proc/hbjax-no-such.csv")
    with pytest.raises(OSError, match=r"cannot write '/proc/hbjax-no-such.csv': its folder "
                                      r"'/proc' takes no new file") as info:
        hbjax.save_recording(target, hbjax.Recording([1.0, 2.0], [3.0, 4.0]))
    assert ".hbjax-" not in str(info.value)


@pytest.mark.parametrize("version", ['"1"', "true", "1.0"])
def test_a_format_version_that_is_no_integer_is_named_as_such(tmp_path, version):
    text = hbjax.save_model(tmp_path / "m.json", M).read_text()
    bad = tmp_path / "v.json"
    bad.write_text(text.replace('"format_version": 1', f'"format_version": {version}'))
    with pytest.raises(hbjax.ModelFileError, match="format_version must be an integer"):
        hbjax.load_model(bad)


@pytest.mark.parametrize("dtype, value", [("float32", 1e308), ("float32", -3.5e38),
                                          ("int32", 2**31), ("int64", -10**30)])
def test_a_value_beyond_its_dtype_is_named_without_a_numpy_warning(tmp_path, dtype, value):
    obj = json.loads(hbjax.save_model(tmp_path / "m.json", M).read_text())
    obj["model"]["fields"]["arx"]["fields"]["a"] = {"array": [value, 0.5 if dtype[0] == "f"
                                                              else 1],
                                                    "dtype": dtype, "shape": [2], "kind": "jax"}
    bad = tmp_path / "big.json"
    bad.write_text(json.dumps(obj))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NumPy's overflow warning would fail the test
        with pytest.raises(hbjax.ModelFileError,
                           match=rf"a\[0\]` \(.+\) is too large for its dtype {dtype}"):
            hbjax.load_model(bad)
