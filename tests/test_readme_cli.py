"""The README's command-line quickstart runs as written in an empty folder."""

import json
import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest

import hbjax

ROOT = pathlib.Path(__file__).resolve().parents[1]


def cli_block() -> str:
    text = (ROOT / "README.md").read_text()
    return re.search(r"<!-- cli quickstart.*?-->\s*```sh\n(.*?)```", text, re.S).group(1)


def test_block_uses_only_files_it_creates():
    # Every file a command reads (--model, --input, --config, or a positional .csv) is written
    # by an earlier line of the block.
    written, lines = set(), cli_block().splitlines()
    for line in lines:
        code = line.split("  #")[0]
        expanded = [code.replace("$k", k) for k in "123"] if "$k" in code else [code]
        for code in expanded:
            reads = re.findall(r"--(?:model|input|config) (\S+)", code)
            if code.startswith("hbjax identify") or code.startswith("hbjax diagnose"):
                reads += [w for w in code.split() if w.endswith(".csv") and not w.startswith("--")]
            missing = [path for path in reads if path not in written]
            assert not missing, f"{line!r} reads {missing} before any line creates them"
            written.update(re.findall(r"'([\w.]+\.(?:json|csv))'", code))
            written.update(re.findall(r"--(?:out|json|plot) (\S+)", code))
            written.update(re.findall(r"> (\S+)", code))
            if "hbjax signals" in code:
                prefix = re.search(r"--prefix (\S+)", code).group(1)
                written.update(f"{prefix}{k}.csv" for k in "123")


@pytest.mark.slow
def test_cli_quickstart_runs_in_an_empty_folder(tmp_path):
    env = dict(os.environ)
    env["PATH"] = str(pathlib.Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env["MPLBACKEND"] = "Agg"
    proc = subprocess.run(
        ["bash", "-e", "-o", "pipefail", "-c", cli_block()],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    made = {
        "true.json", "v1.csv", "v2.csv", "v3.csv", "y1.csv", "y2.csv", "y3.csv", "model.json",
        "u.csv", "rec.csv", "fitted.json", "study_config.json", "study.json", "study.png",
        "report.json", "report.png",
    }
    missing = sorted(name for name in made if not (tmp_path / name).is_file())
    assert not missing, missing
    for name in ("study.png", "report.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The fit from the random-step recording recovers the true linear block.
    truth = hbjax.default_system()
    fitted = hbjax.load_model(tmp_path / "fitted.json")
    np.testing.assert_allclose(np.asarray(fitted.arx.a), np.asarray(truth.arx.a), atol=0.02)
    # The study covered both record lengths, and the report names at least one finding.
    study = json.loads((tmp_path / "study.json").read_text())
    assert "1000" in json.dumps(study) and "4000" in json.dumps(study)
    assert json.loads((tmp_path / "report.json").read_text())
