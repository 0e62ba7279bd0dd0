"""The package's shape: no global side effects on import, public names only in user-facing
material, model files naming registered types."""

import json
import pathlib
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)


@pytest.mark.parametrize("setting", [False, True])
def test_import_leaves_x64_as_the_user_set_it(setting):
    proc = _run(
        "import jax\n"
        f"jax.config.update('jax_enable_x64', {setting})\n"
        "import hbjax, hbjax.plot, hbjax.internal, hbjax.datasets\n"
        "print(jax.config.read('jax_enable_x64'))\n"
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(setting)


def test_without_x64_simulator_stays_float32_and_estimators_say_how_to_enable():
    proc = _run(
        "import jax, jax.numpy as jnp, numpy as np, hbjax\n"
        "m = hbjax.default_system()\n"
        "v = jnp.ones(50, jnp.float32)\n"
        "print(m.arx.a.dtype, hbjax.simulate(m, v).dtype, hbjax.play(m.backlash, v).dtype,"
        " hbjax.predict(m, v, v).dtype)\n"
        "try:\n"
        "    hbjax.refine(m, [(np.ones(50), np.ones(50))], h_m=4.0)\n"
        "except RuntimeError as e:\n"
        "    print('ERR', e)\n"
    )
    assert proc.returncode == 0, proc.stderr
    first, second = proc.stdout.strip().splitlines()
    assert first.split() == ["float32"] * 4
    assert second.startswith("ERR refine needs float64")
    assert "jax.config.update('jax_enable_x64', True)" in second


def test_float32_model_and_input_stay_float32_under_x64():
    model = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), hbjax.default_system())
    v = jnp.linspace(-5.0, 5.0, 64, dtype=jnp.float32)
    y = hbjax.simulate(model, v)
    assert y.dtype == jnp.float32
    grad = jax.grad(lambda m: jnp.sum(hbjax.simulate(m, v) ** 2))(model)
    assert grad.arx.a.dtype == jnp.float32
    y64 = hbjax.simulate(hbjax.default_system(), np.asarray(v, np.float64))
    np.testing.assert_allclose(np.asarray(y), np.asarray(y64), rtol=1e-4, atol=1e-4)


def _user_facing_text():
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for path in files:
        yield path, path.read_text()
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        nb = json.loads(path.read_text())
        yield path, "\n".join("".join(c["source"]) for c in nb["cells"])


def test_readme_docs_and_notebooks_use_only_public_names():
    private = re.compile(r"\bhbjax\._\w+|from hbjax import _\w+")
    offenders = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p, text in _user_facing_text()
                 for m in private.finditer(text)]
    assert offenders == []


def test_plot_module_is_reachable_from_a_plain_import():
    proc = _run("import sys, hbjax\n"
                "print('matplotlib' in sys.modules)\n"
                "print(callable(hbjax.plot.plot_diagnosis))\n")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "True"]


def test_model_files_name_registered_public_types(tmp_path):
    path = hbjax.save_model(tmp_path / "m.json", hbjax.default_system())
    doc = json.loads(pathlib.Path(path).read_text())
    assert doc["model"]["class"] == "Hammerstein"
    assert doc["model"]["fields"]["backlash"]["class"] == "Backlash"
    assert doc["model"]["fields"]["arx"]["class"] == "ARX"


def test_model_files_of_version_0_1_0_still_load(tmp_path):
    path = hbjax.save_model(tmp_path / "m.json", hbjax.default_system())
    text = pathlib.Path(path).read_text()
    for new, old in [("Hammerstein", "hbjax._model.Hammerstein"),
                     ("Backlash", "hbjax._backlash.Backlash"), ("ARX", "hbjax._arx.ARX")]:
        text = text.replace(f'"class": "{new}"', f'"class": "{old}"')
    old_file = tmp_path / "old.json"
    old_file.write_text(text)
    loaded = hbjax.load_model(old_file)
    np.testing.assert_array_equal(hbjax.flatten_params(loaded),
                                  hbjax.flatten_params(hbjax.default_system()))


@pytest.mark.parametrize("name", ["hbjax.__main__.X", "hbjax._cli.parser.main", "os.system",
                                  "hbjax._core.model.Hammerstein", "Hammerstein2"])
def test_model_files_naming_anything_else_import_nothing(tmp_path, name):
    path = hbjax.save_model(tmp_path / "m.json", hbjax.default_system())
    text = pathlib.Path(path).read_text().replace('"class": "Hammerstein"', f'"class": "{name}"')
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    before = set(sys.modules)
    with pytest.raises(ValueError, match="unknown model class"):
        hbjax.load_model(bad)
    assert set(sys.modules) == before


def _quickstart_records(n=600, sigma=0.3):
    model, design = hbjax.default_system(), hbjax.default_design()
    inputs = [design.constant_input(n), design.binary_input(n), design.staircase_input(n)]
    keys = jax.random.split(jax.random.key(0), 3)
    outputs = [hbjax.simulate(model, v, sigma * jax.random.normal(k, (n,)))
               for v, k in zip(inputs, keys)]
    return model, design, inputs, outputs


def test_one_result_enumeration_for_closed_form_refinement_and_fit():
    import optimistix as optx

    assert issubclass(hbjax.RESULTS, optx.RESULTS)
    model, design, inputs, outputs = _quickstart_records()
    giri = hbjax.identify_giri(design, *outputs)
    assert giri.result == hbjax.RESULTS.successful and giri.message == "success"
    zeros = [jnp.zeros_like(y) for y in outputs]
    failed = hbjax.identify_giri(design, *zeros, throw=False)
    assert failed.result != hbjax.RESULTS.successful
    assert failed.message == hbjax.RESULTS[failed.result]
    refined = hbjax.refine(giri.model, list(zip(inputs, outputs)), h_m=design.h_m, max_steps=1,
                           restarts=0, throw=False)
    assert refined.result == hbjax.RESULTS.nonlinear_max_steps_reached


def test_throw_raises_under_jit_too():
    model, design, inputs, outputs = _quickstart_records()
    start = hbjax.identify_giri(design, *outputs).model
    records = list(zip(inputs, outputs))

    @jax.jit
    def refine_model(records):
        return hbjax.refine(start, records, h_m=design.h_m, max_steps=1).model

    with pytest.raises(Exception, match="maximum number of steps"):
        jax.block_until_ready(refine_model(records))

    @jax.jit
    def closed_form(y1, y2, y3):
        return hbjax.identify_giri(design, y1, y2, y3).model

    zeros = [jnp.zeros_like(y) for y in outputs]
    with pytest.raises(Exception, match="singular|assumption"):
        jax.block_until_ready(closed_form(*zeros))
    # throw=False under jit returns the failure as a value instead
    quiet = jax.jit(lambda r: hbjax.refine(start, r, h_m=design.h_m, max_steps=1,
                                           throw=False).result)(records)
    assert quiet == hbjax.RESULTS.nonlinear_max_steps_reached


def test_arrays_on_different_devices_are_refused_by_name():
    code = (
        "import jax, numpy as np\n"
        "jax.config.update('jax_enable_x64', True)\n"
        "import hbjax\n"
        "d = jax.devices()\n"
        "m = hbjax.default_system()\n"
        "v = jax.device_put(np.linspace(-5, 5, 60), d[0])\n"
        "y = jax.device_put(np.zeros(60), d[1])\n"
        "try:\n"
        "    hbjax.refine(m, [(v, y)], h_m=4.0)\n"
        "except ValueError as e:\n"
        "    print(e)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ,
                               "XLA_FLAGS": __import__("os").environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2"})
    assert proc.returncode == 0, proc.stderr
    assert "different devices" in proc.stdout and "`recordings[0] y` on" in proc.stdout
