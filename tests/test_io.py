"""Recordings (CSV/NPZ/JSON) and model files: round trips, clear errors, no clobbering."""

import dataclasses
import json
import os
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._io.modelfile import ModelFileError, model_from_json, model_to_json


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def bits(x):
    return np.asarray(x).tobytes()


def assert_bitwise_equal(m1, m2):
    l1, t1 = jax.tree.flatten(m1)
    l2, t2 = jax.tree.flatten(m2)
    assert type(m1) is type(m2)
    assert t1 == t2
    for a, b in zip(l1, l2):
        assert type(a) is type(b)
        assert np.asarray(a).dtype == np.asarray(b).dtype
        assert np.shape(a) == np.shape(b)
        assert bits(a) == bits(b)


# ----------------------------------------------------------------------------- Recording


def test_recording_validates_and_is_read_only():
    rec = hbjax.Recording([1, 2, 3], [0.5, 0.25, 0.0], dt=2, source="s", name="n")
    assert rec.v.dtype == np.float64 and len(rec) == 3 and rec.dt == 2.0
    np.testing.assert_array_equal(rec.t, [0.0, 2.0, 4.0])
    with pytest.raises(ValueError):
        rec.v[0] = 7.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        rec.dt = 1.0
    with pytest.raises(ValueError, match="equal lengths"):
        hbjax.Recording([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="`y` contains NaN.*index 1"):
        hbjax.Recording([1.0, 2.0], [1.0, np.nan])
    with pytest.raises(ValueError, match="`dt`"):
        hbjax.Recording([1.0], [1.0], dt=-1.0)
    with pytest.raises(ValueError, match="1-D"):
        hbjax.Recording(np.ones((2, 2)), np.ones((2, 2)))
    assert len(rec.slice(1)) == 2 and rec.slice(1).v[0] == 2.0


def test_recording_refuses_empty_records_and_bad_time_origins(tmp_path):
    # An empty record was accepted and written, but its file could not be read back.
    with pytest.raises(ValueError, match="`v` is empty"):
        hbjax.Recording(np.array([]), np.array([]))
    with pytest.raises(ValueError, match="`y` is empty"):
        hbjax.Recording([1.0], np.array([]))
    rec = hbjax.Recording(np.arange(5.0), np.arange(5.0))
    for start, stop in ((5, 2), (3, 3), (7, None), (None, -5)):
        with pytest.raises(ValueError, match=f"`start`={start!r}, `stop`={stop!r} keep no"):
            rec.slice(start, stop)
    assert len(rec.slice(-1)) == 1 and len(rec.slice(None, 99)) == 5
    for t0 in (np.nan, np.inf, -np.inf, 10**400):
        with pytest.raises(ValueError, match="`t0` must be a finite real number"):
            hbjax.Recording([1.0], [1.0], dt=1.0, t0=t0)
    for t0 in ("0", None, True, [0.0]):
        with pytest.raises(TypeError, match="`t0` must be a finite real number"):
            hbjax.Recording([1.0], [1.0], t0=t0)
    assert hbjax.Recording([1.0], [1.0], t0=np.int64(3)).t0 == 3.0
    # A NaN time origin in a file is refused by name too.
    np.savez(tmp_path / "r.npz", v=[1.0], y=[2.0], t0=np.float64(np.nan))
    with pytest.raises(ValueError, match="r.npz: `t0` must be a finite"):
        hbjax.load_recording(tmp_path / "r.npz")


def test_a_dt_the_file_contradicts_is_refused(tmp_path):
    p = write(tmp_path, "r.csv", "t,v,y\n" + "".join(f"{k},{k},{k}\n" for k in range(10)))
    with pytest.raises(ValueError, match=r"r.csv: `dt`=5.0 conflicts with the step of the "
                                         r"time column 't' \(1\); give only one"):
        hbjax.load_recording(p, time="t", dt=5)
    assert hbjax.load_recording(p, time="t", dt=1).dt == 1.0
    assert hbjax.load_recording(p, time="t", dt=1.0005).dt == 1.0005  # within 0.1 %
    assert hbjax.load_recording(p, dt=5).dt == 5.0  # no time column named: nothing to contradict
    with pytest.raises(TypeError, match="`dt` must be a positive float"):
        hbjax.load_recording(p, time="t", dt="1")
    # The file's own dt (save_recording's comment line, an NPZ entry) is contradicted alike.
    for suffix in ("csv", "npz"):
        saved = hbjax.save_recording(tmp_path / f"s.{suffix}",
                                     hbjax.Recording([1.0, 2.0], [3.0, 4.0], dt=0.5))
        with pytest.raises(ValueError, match="conflicts with the file's own dt \\(0.5\\)"):
            hbjax.load_recording(saved, dt=5)
        assert hbjax.load_recording(saved, dt=0.5).dt == 0.5
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame({"t": np.arange(10.0), "v": np.arange(10.0), "y": np.arange(10.0)})
    with pytest.raises(ValueError, match="`dt`=5.0 conflicts with the step of the time column"):
        hbjax.Recording.from_dataframe(df, input="v", output="y", time="t", dt=5)
    assert hbjax.Recording.from_dataframe(df, input="v", output="y", time="t", dt=1).dt == 1.0


# ----------------------------------------------------------------------------- CSV


def test_csv_header_names_and_indices(tmp_path):
    p = write(tmp_path, "r.csv", "time,force,disp\n0.0,1.5,-1\n0.5,2.5,-2\n1.0,3.5,-3\n")
    rec = hbjax.load_recording(p, input="disp", output="force", time="time")
    np.testing.assert_array_equal(rec.v, [-1.0, -2.0, -3.0])
    np.testing.assert_array_equal(rec.y, [1.5, 2.5, 3.5])
    assert rec.dt == 0.5 and rec.name == "r" and rec.source == str(p)
    by_index = hbjax.load_recording(p, input=2, output=1)
    np.testing.assert_array_equal(by_index.v, rec.v)
    assert by_index.dt is None
    default = hbjax.load_recording(p)
    np.testing.assert_array_equal(default.v, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(default.y, [1.5, 2.5, 3.5])


def test_csv_without_header_other_delimiters_comments(tmp_path):
    p = write(tmp_path, "a.txt", "# a comment\n1 2\n\n3   4\n")
    rec = hbjax.load_recording(p, dt=0.1)
    np.testing.assert_array_equal(rec.v, [1.0, 3.0])
    np.testing.assert_array_equal(rec.y, [2.0, 4.0])
    assert rec.dt == 0.1
    p = write(tmp_path, "b.csv", "u;y\n1;2\n3;4\n")
    np.testing.assert_array_equal(hbjax.load_recording(p, input="u", output="y").y, [2.0, 4.0])
    with pytest.raises(ValueError, match="no header row"):
        hbjax.load_recording(write(tmp_path, "c.csv", "1,2\n3,4\n"), input="u")


def test_csv_float_text_round_trips_exactly(tmp_path):
    rng = np.random.default_rng(0)
    rec = hbjax.Recording(rng.normal(size=50) * 1e-7, rng.normal(size=50) * 1e9, dt=1 / 1024)
    p = hbjax.save_recording(tmp_path / "x.csv", rec)
    back = hbjax.load_recording(p, input="v", output="y", time="t")
    assert bits(back.v) == bits(rec.v) and bits(back.y) == bits(rec.y)
    assert back.dt == rec.dt


@pytest.mark.parametrize(
    "text, kwargs, pattern",
    [
        ("a,b\n1,2\n3,x\n", {}, r"non-numeric cell 'x' at row 3, column 1 \('b'\)"),
        ("a,b\n1,2\n3,\n", {}, r"empty cell at row 3, column 1 \('b'\)"),
        ("a,b\n1,2\n3,4,5\n", {}, r"ragged row 3: 3 cells, but the header has 2"),
        ("a,b\n1,2\n\n3,nan\n", {}, r"'nan' \(not finite\) at row 4, column 1 \('b'\)"),
        ("a,b\n1,2\n", {"input": "c"}, r"no input column named 'c' \(columns: 'a', 'b'\)"),
        ("a,b\n1,2\n", {"output": 5}, r"output column index 5 is out of range"),
        ("", {}, r"empty"),
        ("\n# only a comment\n", {}, r"empty"),
        ("a,b\n", {}, r"header row but no data rows"),
        ("a,b,c\n0,1,2\n1,2,3\n3,3,4\n", {"time": "a", "input": "b", "output": "c"},
         r"not uniformly sampled"),
        ("a,b\n0,1\n1,2\n", {"time": "a"}, r"the input and the time are the same column"),
    ],
)
def test_csv_errors_name_row_and_column(tmp_path, text, kwargs, pattern):
    p = write(tmp_path, "bad.csv", text)
    with pytest.raises(ValueError, match=pattern) as info:
        hbjax.load_recording(p, **kwargs)
    assert str(p) in str(info.value)


def test_unused_columns_may_hold_anything(tmp_path):
    # The Cascaded Tanks file has a Ts column filled only in its first row.
    p = write(tmp_path, "t.csv", '"u","y","Ts",\n1,2,4,\n3,4,,\n')
    rec = hbjax.load_recording(p)
    np.testing.assert_array_equal(rec.y, [2.0, 4.0])
    with pytest.raises(ValueError, match=r"empty cell at row 3, column 2 \('Ts'\)"):
        hbjax.load_recording(p, time="Ts")


def test_other_numeric_columns_of_any_csv_are_channels(tmp_path):
    # Offered to diagnose (docs/io_and_cli.md); a column of notes or blanks is left out.
    p = write(tmp_path, "c.csv", "drive,force,aux,note,aux\n1,2,3,a,5\n4,5,6,b,7\n")
    rec = hbjax.load_recording(p)
    assert list(rec.channels) == ["aux", "aux (column 4)"]
    np.testing.assert_array_equal(rec.channels["aux"], [3.0, 6.0])
    q = write(tmp_path, "n.csv", "1 2 9\n3 4 8\n")
    np.testing.assert_array_equal(hbjax.load_recording(q).channels["column 2"], [9.0, 8.0])
    assert dict(hbjax.load_recording(q, output=2).channels) .keys() == {"column 1"}
    # a time axis is not a recorded signal
    r = write(tmp_path, "t.csv", "time,v,y,temp\n0,1,2,3\n1,4,5,6\n")
    assert list(hbjax.load_recording(r, input="v", output="y").channels) == ["temp"]


def test_a_brfd_files_other_columns_are_its_channels():
    import importlib.resources

    name = "1Hz30lbtension1amplitude"
    path = importlib.resources.files("hbjax") / "data" / "brfd" / f"{name}.json"
    loaded, bundled = hbjax.load_recording(str(path)), hbjax.datasets.brfd(name)
    assert list(loaded.channels) == list(bundled.channels) == [
        "velocity", "actuator force 1", "actuator force 2"]
    for k in bundled.channels:
        np.testing.assert_array_equal(loaded.channels[k], bundled.channels[k])


def test_missing_file_and_binary_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        hbjax.load_recording(tmp_path / "nope.csv")
    p = tmp_path / "bin.csv"
    p.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(ValueError, match="not a text"):
        hbjax.load_recording(p)


# ----------------------------------------------------------------------------- NPZ, JSON


def test_npz(tmp_path):
    p = tmp_path / "r.npz"
    np.savez(p, v=np.arange(4.0), y=np.arange(4.0) ** 2, dt=0.25)
    rec = hbjax.load_recording(p)
    np.testing.assert_array_equal(rec.y, [0.0, 1.0, 4.0, 9.0])
    assert rec.dt == 0.25
    q = tmp_path / "s.npz"
    np.savez(q, drive=np.ones(3), response=np.array([1.0, np.nan, 2.0]),
             level=np.arange(3.0))
    assert hbjax.load_recording(q, output=2).y.shape == (3,)
    with pytest.raises(ValueError, match=r"array 'response' has NaN or inf at index 1"):
        hbjax.load_recording(q)
    with pytest.raises(ValueError, match=r"the input and the output are the same column"):
        hbjax.load_recording(q, output=0)  # the default input is the first array too
    with pytest.raises(ValueError, match=r"no input array named 'x'; arrays: \['drive', 'response', 'level'\]"):
        hbjax.load_recording(q, input="x")
    bad = write(tmp_path, "junk.npz", "not a zip")
    with pytest.raises(ValueError, match="not a readable .npz"):
        hbjax.load_recording(bad)


def test_brfd_layout_json(tmp_path):
    doc = {"data": [[0.0, 0.1, 1.0, 9, 9, 9], [0.5, 0.2, 2.0, 9, 9, 9]], "dt": 0.5}
    p = write(tmp_path, "b.json", json.dumps(doc))
    rec = hbjax.load_recording(p)
    np.testing.assert_array_equal(rec.v, [0.1, 0.2])
    np.testing.assert_array_equal(rec.y, [1.0, 2.0])
    assert rec.dt == 0.5
    rec2 = hbjax.load_recording(p, input="time", output="velocity")
    np.testing.assert_array_equal(rec2.v, [0.0, 0.5])
    doc["data"][1] = [0.5, 0.2]
    with pytest.raises(ValueError, match="ragged row 1"):
        hbjax.load_recording(write(tmp_path, "r.json", json.dumps(doc)))
    doc["data"][1] = [0.5, 0.2, "x", 9, 9, 9]
    with pytest.raises(ValueError, match=r"non-numeric value 'x' at data row 1, column 2"):
        hbjax.load_recording(write(tmp_path, "n.json", json.dumps(doc)))
    with pytest.raises(ValueError, match="BRFD JSON layout"):
        hbjax.load_recording(write(tmp_path, "f.json", '{"rows": []}'))
    with pytest.raises(ValueError, match="not valid JSON"):
        hbjax.load_recording(write(tmp_path, "c.json", '{"data": [[1, 2'))


# ----------------------------------------------------------------------------- writers


def test_writers_do_not_clobber_and_leave_no_temp_files(tmp_path, system):
    p = tmp_path / "m.json"
    hbjax.save_model(p, system)
    before = p.read_bytes()
    other = hbjax.normalise(system, 4.0)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        hbjax.save_model(p, other)
    assert p.read_bytes() == before
    hbjax.save_model(p, other, overwrite=True)
    assert_bitwise_equal(hbjax.load_model(p), other)
    rec = hbjax.Recording([1.0], [2.0])
    hbjax.save_recording(tmp_path / "r.csv", rec)
    with pytest.raises(FileExistsError):
        hbjax.save_recording(tmp_path / "r.csv", rec)
    assert sorted(os.listdir(tmp_path)) == ["m.json", "r.csv"]


def test_interrupted_write_keeps_old_file(tmp_path, system, monkeypatch):
    p = tmp_path / "m.json"
    hbjax.save_model(p, system)
    before = p.read_bytes()

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(OSError, match="disk full"):
        hbjax.save_model(p, hbjax.normalise(system, 4.0), overwrite=True)
    assert p.read_bytes() == before
    assert os.listdir(tmp_path) == ["m.json"]


# ----------------------------------------------------------------------------- model files


def test_model_file_round_trip_is_bitwise(tmp_path, system):
    key = jax.random.PRNGKey(0)
    theta = jax.random.normal(key, (10,)) * jnp.array([1e-300, 1e300, 1 / 3, -0.0, 1, 2, 3, 4, 5, 6])
    model = hbjax.unflatten_params(system, theta)
    p = hbjax.save_model(tmp_path / "m.json", model)
    back = hbjax.load_model(p)
    assert_bitwise_equal(back, model)
    doc = json.loads(p.read_text())
    assert doc["format"] == "hbjax-model" and doc["kind"] == "Hammerstein"
    assert doc["hbjax_version"] == hbjax.__version__
    np.testing.assert_array_equal(hbjax.simulate(back, jnp.ones(20)), hbjax.simulate(model, jnp.ones(20)))


class Gain(eqx.Module):
    k: jax.Array


class SaturatedHammerstein(hbjax.AbstractModel):
    """An extension as the diagnosis would write one: a wrapped core, array and static fields."""

    core: hbjax.Hammerstein
    limit: float = eqx.field(static=True)
    delay: int = eqx.field(static=True)
    offset: jax.Array
    note: str | None = eqx.field(static=True, default=None)
    scale: float | None = eqx.field(static=True, default=None)
    gains: tuple = ()
    table: np.ndarray | None = None

    def __check_init__(self):
        if self.limit <= 0:
            raise ValueError("`limit` must be positive.")

    def simulate_trajectory(self, v, noise, u0):
        y = self.core.simulate_trajectory(v, noise, u0)
        return jnp.clip(hbjax._core.model.lagged(y, self.delay), -self.limit, self.limit) + self.offset

    def predict_trajectory(self, v, y, u0):
        return self.core.predict_trajectory(v, y, u0) + self.offset


def make_extension(system):
    return SaturatedHammerstein(
        core=system,
        limit=2.5,
        delay=2,
        offset=jnp.asarray(0.1),
        note=None,
        scale=float("inf"),
        gains=(Gain(jnp.array([1.0, 2.0], dtype=jnp.float32)), jnp.array([3, 4]), 0.5, None),
        table=np.array([[1.0, np.nan], [-np.inf, 0.1]]),
    )


def test_extended_model_round_trip(tmp_path, system):
    model = make_extension(system)
    p = hbjax.save_model(tmp_path / "ext.json", model)
    with pytest.raises(ModelFileError, match="unknown model class .*Gain"):
        hbjax.load_model(p)  # a nested non-hbjax module must be allowed explicitly
    back = hbjax.load_model(p, classes=[Gain])
    assert_bitwise_equal(back, model)
    assert back.limit == 2.5 and back.delay == 2 and back.note is None and back.scale == np.inf
    assert isinstance(back.gains[0].k, jax.Array) and back.gains[0].k.dtype == jnp.float32
    assert isinstance(back.table, np.ndarray)
    np.testing.assert_array_equal(back.table, model.table)
    v = jnp.linspace(-4, 4, 30)
    np.testing.assert_array_equal(hbjax.simulate(back, v), hbjax.simulate(model, v))
    assert json.loads(p.read_text())["kind"] == "SaturatedHammerstein"


def test_extended_model_invariants_checked_on_load(system):
    text = model_to_json(make_extension(system)).replace('"limit": 2.5', '"limit": -1.0')
    with pytest.raises(ModelFileError, match="limit.*positive"):
        model_from_json(text, classes=[Gain])


def test_unserialisable_field_is_refused(tmp_path, system):
    class WithFunction(hbjax.AbstractModel):
        core: hbjax.Hammerstein
        f: object = eqx.field(static=True)

        def simulate_trajectory(self, v, noise, u0):
            return self.core.simulate_trajectory(v, noise, u0)

        def predict_trajectory(self, v, y, u0):
            return self.core.predict_trajectory(v, y, u0)

    with pytest.raises(TypeError, match="cannot save `model.f` of type function"):
        hbjax.save_model(tmp_path / "f.json", WithFunction(system, lambda x: x))
    assert not (tmp_path / "f.json").exists()
    with pytest.raises(TypeError, match="hbjax model"):
        hbjax.save_model(tmp_path / "g.json", system.arx)


def _mutations(text):
    doc = json.loads(text)

    def edit(fn):
        d = json.loads(text)
        fn(d)
        return json.dumps(d)

    back = lambda d: d["model"]["fields"]["backlash"]["fields"]  # noqa: E731
    yield "truncated", text[: len(text) // 2], "not a valid JSON"
    yield "foreign", json.dumps({"weights": [1, 2]}), "not an hbjax model file"
    yield "list", "[1, 2, 3]", "not an hbjax model file"
    yield "newer", edit(lambda d: d.update(format_version=99)), "format_version 99"
    yield "class", edit(lambda d: d["model"].update({"class": "os.system"})), "unknown model class 'os.system'"
    yield "kind", edit(lambda d: d.update(kind="Other")), "disagrees"
    yield "missing", edit(lambda d: back(d).pop("c2")), r"missing fields \['c2'\]"
    yield "extra", edit(lambda d: back(d).update(c3=1.0)), r"unknown fields \['c3'\]"
    yield "shape", edit(lambda d: back(d)["c1"].update(shape=[4])), "must hold 4 values"
    yield "value", edit(lambda d: back(d)["c1"]["array"].__setitem__(0, "x")), r"c1\[0\]` must be a number"
    yield "nan", edit(lambda d: back(d)["c1"]["array"].__setitem__(0, {"float": "nan"})), "non-finite"
    yield "length", edit(lambda d: back(d).update(c2=back(d)["c2"] | {"array": [1.0], "shape": [1]})), "equal length"
    yield "dtype", edit(lambda d: back(d)["c1"].update(dtype="complex128")), "unsupported dtype"
    yield "abstract", edit(lambda d: d["model"].update({"class": "hbjax._model.AbstractModel"})), "abstract"
    assert doc


@pytest.mark.parametrize("case", [m[0] for m in _mutations(model_to_json(hbjax.default_system()))])
def test_corrupted_model_file_gives_clear_error(tmp_path, case):
    cases = {name: (text, msg) for name, text, msg in _mutations(model_to_json(hbjax.default_system()))}
    text, message = cases[case]
    p = write(tmp_path, "bad.json", text)
    with pytest.raises(ValueError, match=message) as info:
        hbjax.load_model(p)
    assert str(p) in str(info.value)


def test_model_file_is_strict_json(system):
    text = model_to_json(make_extension(system))
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


@pytest.mark.parametrize("effect", sorted(hbjax.EFFECTS))
def test_diagnosis_extensions_round_trip(tmp_path, effect):
    """Every extended model of the diagnosis is a model file like any other."""
    rec = hbjax.concealed_recording(effect, n=200, key=jax.random.PRNGKey(1))
    p = hbjax.save_model(tmp_path / "m.json", rec.true_model)
    back = hbjax.load_model(p)
    assert_bitwise_equal(back, rec.true_model)
    assert json.loads(p.read_text())["kind"] == type(rec.true_model).__name__
    np.testing.assert_array_equal(hbjax.simulate(back, rec.v), hbjax.simulate(rec.true_model, rec.v))


def test_file_from_before_a_field_with_a_default_was_added_still_loads(system):
    # level_dependent_dynamics gained its `datum` (default: the outlet) after files were
    # written without it; such a file loads with the default and simulates as before
    fx = hbjax.EFFECTS["level_dependent_dynamics"](system, jnp.asarray(0.5), jnp.asarray(0.3),
                                                  jnp.asarray(1.0), jnp.asarray(2.0))
    doc = json.loads(model_to_json(fx))
    assert doc["model"]["fields"].pop("datum") is None
    back = model_from_json(json.dumps(doc))
    assert back.datum is None
    v = jnp.linspace(-4, 4, 60)
    np.testing.assert_array_equal(hbjax.simulate(back, v), hbjax.simulate(fx, v))
    # a field without a default is still required
    doc["model"]["fields"].pop("alpha")
    with pytest.raises(ModelFileError, match=r"missing fields \['alpha'\]"):
        model_from_json(json.dumps(doc))


def test_written_files_get_ordinary_permissions(tmp_path, system):
    umask = os.umask(0o022)
    try:
        p = hbjax.save_model(tmp_path / "m.json", system)
    finally:
        os.umask(umask)
    assert p.stat().st_mode & 0o777 == 0o644


def test_float64_file_loaded_without_x64_is_refused_unless_exact(tmp_path):
    # JAX's 32-bit mode would round float64 coefficients silently (-1.2 -> -1.2000000477).
    exact = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [1.0, 1.0]), hbjax.ARX([-1.25, 0.5], [1.0, 0.5]))
    rounded = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [1.0, 1.0]), hbjax.ARX([-1.2, 0.5], [1.0, 0.3]))
    hbjax.save_model(tmp_path / "exact.json", exact)
    hbjax.save_model(tmp_path / "rounded.json", rounded)
    script = (
        "import hbjax, sys\n"
        "m = hbjax.load_model(sys.argv[1])\n"
        "print(m.arx.a.dtype, float(m.arx.a[0]))\n"
        "try:\n"
        "    hbjax.load_model(sys.argv[2])\n"
        "except hbjax.ModelFileError as exc:\n"
        "    print('refused:', exc)\n")
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    out = subprocess.run([sys.executable, "-c", script, str(tmp_path / "exact.json"),
                          str(tmp_path / "rounded.json")], env=dict(env, JAX_PLATFORMS="cpu"),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "float32 -1.25"
    assert lines[1].startswith("refused:") and "jax_enable_x64" in lines[1]
