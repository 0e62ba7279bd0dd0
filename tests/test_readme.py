"""The README quickstart runs and its result is right."""

import re
from pathlib import Path

import numpy as np


def test_readme_quickstart_runs(capsys):
    text = (Path(__file__).parent.parent / "README.md").read_text()
    block = re.search(r"<!-- quickstart.*?-->\s*```python\n(.*?)```", text, re.S).group(1)
    assert len(block.strip().splitlines()) <= 20
    namespace = {}
    exec(compile(block, "README.md", "exec"), namespace)
    hbjax = namespace["hbjax"]
    err = np.asarray(hbjax.flatten_params(namespace["result"].model) - hbjax.flatten_params(namespace["truth"]))
    # A and B* are accurate; the branches are extrapolated from [h_m, 2h_m] (see notebook 01).
    assert np.all(np.abs(err[:4]) < 0.1)
    assert "a1" in capsys.readouterr().out

    # The continuation refines the same estimate and computes the bound.
    more = re.search(r"<!-- quickstart continued.*?-->\s*```python\n(.*?)```", text, re.S).group(1)
    exec(compile(more, "README.md", "exec"), namespace)
    refined, bound = namespace["refined"], namespace["bound"]
    assert refined.message == "success"
    truth_flat = np.asarray(hbjax.flatten_params(namespace["truth"]))
    refined_err = np.asarray(hbjax.flatten_params(refined.model)) - truth_flat
    # Within 5 standard errors of the truth, and the bound is a proper covariance.
    assert np.all(np.abs(refined_err) < 5 * np.asarray(refined.std) + 1e-12)
    assert np.all(np.diag(np.asarray(bound.covariance)) >= 0)
