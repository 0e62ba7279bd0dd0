"""Bundled recordings: shapes, sampling periods, values equal to the shipped files."""

import csv
import importlib.resources
import json

import numpy as np
import pytest

import hbjax
from hbjax import datasets

DATA = importlib.resources.files("hbjax") / "data"


def test_cascaded_tanks_matches_file():
    est, val = datasets.cascaded_tanks()
    assert isinstance(est, hbjax.Recording) and isinstance(val, hbjax.Recording)
    assert len(est) == len(val) == 1024
    assert est.dt == val.dt == 4.0
    with (DATA / "cascaded_tanks" / "dataBenchmark.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["uEst"]]
    for rec, u, y in ((est, "uEst", "yEst"), (val, "uVal", "yVal")):
        np.testing.assert_array_equal(rec.v, [float(r[u]) for r in rows])
        np.testing.assert_array_equal(rec.y, [float(r[y]) for r in rows])
    # The documented sensor saturation: samples stuck at exactly 10.0 in both records.
    assert np.any(est.y == 10.0) and np.any(val.y == 10.0) and est.y.max() == 10.0
    assert est.name == "cascaded_tanks_estimation" and val.name == "cascaded_tanks_validation"


def test_cascaded_tanks_also_loads_through_load_recording():
    path = DATA / "cascaded_tanks" / "dataBenchmark.csv"
    with importlib.resources.as_file(path) as p:
        rec = hbjax.load_recording(p, input="uVal", output="yVal", dt=4.0)
    np.testing.assert_array_equal(rec.v, datasets.cascaded_tanks()[1].v)


def test_brfd_names_and_records():
    names = datasets.brfd_names()
    assert "1Hz30lbtension1amplitude" in names and len(names) == 4
    for name in names:
        rec = datasets.brfd(name)
        doc = json.loads((DATA / "brfd" / f"{name}.json").read_text())
        data = np.asarray(doc["data"])
        np.testing.assert_array_equal(rec.v, data[:, 1])
        np.testing.assert_array_equal(rec.y, data[:, 2])
        assert rec.dt == 1 / 1024 and rec.name == name
        np.testing.assert_allclose(np.diff(data[:, 0]), rec.dt)
        # A sinusoidal displacement of about the amplitude in the file name.
        amplitude = float(name.split("tension")[1].removesuffix("amplitude"))
        assert 0.8 * amplitude < np.abs(rec.v).max() < 1.2 * amplitude


def test_brfd_load_recording_agrees():
    with importlib.resources.as_file(DATA / "brfd" / "1Hz30lbtension1amplitude.json") as p:
        rec = hbjax.load_recording(p)
    ref = datasets.brfd("1Hz30lbtension1amplitude")
    np.testing.assert_array_equal(rec.v, ref.v)
    np.testing.assert_array_equal(rec.y, ref.y)
    assert rec.dt == ref.dt


def test_brfd_unknown_name_lists_valid_names():
    with pytest.raises(ValueError, match="valid names: .*1Hz30lbtension1amplitude"):
        datasets.brfd("2Hz")
    assert len(datasets.brfd("1Hz30lbtension1amplitude.json")) == 7169


def test_records_are_read_only_so_cached_copies_stay_intact():
    rec = datasets.brfd("1Hz30lbtension1amplitude")
    with pytest.raises(ValueError):
        rec.y[0] = 1.0


def test_licence_and_provenance_ship_with_the_data():
    assert (DATA / "brfd" / "LICENSE-CC-BY-SA-4.0.txt").read_bytes().count(b"Attribution-ShareAlike") >= 1
    readme = (DATA / "README.md").read_text()
    assert "Schoukens" in readme and "Coble" in readme and "CC BY-SA 4.0" in readme
    assert "bibtex" in (DATA / "CITATION.md").read_text()
