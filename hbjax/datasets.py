"""Real recordings shipped inside the package (``hbjax/data/``), loadable offline.

- :func:`cascaded_tanks`: the Cascaded Tanks benchmark (Schoukens, Mattsson, Wigren, Noel,
  2016), estimation and validation records.
- :func:`brfd`: banded rotary friction device characterisation tests (Coble, Huggins, Cao,
  Ricles, Downey, ARTS Lab, 2022; CC BY-SA 4.0), a friction damper with backlash.

Provenance, licences and citations: ``hbjax/data/README.md``. The numbers are unmodified.
"""

from __future__ import annotations

import functools
import importlib.resources
import json

import numpy as np

from ._io.recording import BRFD_COLUMNS, Recording

__all__ = ["brfd", "brfd_names", "cascaded_tanks"]

_DATA = importlib.resources.files("hbjax") / "data"


def cascaded_tanks() -> tuple[Recording, Recording]:
    """The Cascaded Tanks benchmark: ``(estimation, validation)`` records.

    Input ``v``: pump voltage (V, columns ``uEst``/``uVal``); output ``y``: water level of the
    lower tank as a sensor voltage (V, ``yEst``/``yVal``); 1024 samples each, ``dt = 4`` s.
    The level sensor saturates at 10 V (samples stuck at exactly 10.0 in both records), and the
    upper tank overflows: soft and hard nonlinearities, not an HB-Hammerstein system.

    Cite: M. Schoukens, P. Mattsson, T. Wigren, J.-P. Noel, "Cascaded tanks benchmark combining
    soft and hard nonlinearities", Workshop on Nonlinear System Identification Benchmarks, 2016.
    """
    return _cascaded_tanks()


@functools.lru_cache(maxsize=1)
def _cascaded_tanks():
    text = (_DATA / "cascaded_tanks" / "dataBenchmark.csv").read_text(encoding="utf-8")
    lines = [line for line in text.splitlines() if line.strip()]
    header = [h.strip().strip('"') for h in lines[0].split(",")]
    cols = {name: [] for name in ("uEst", "uVal", "yEst", "yVal")}
    index = {name: header.index(name) for name in cols}
    for line in lines[1:]:
        cells = line.split(",")
        for name, j in index.items():
            cols[name].append(float(cells[j]))
    ts = float(lines[1].split(",")[header.index("Ts")])
    source = "hbjax.datasets:cascaded_tanks"
    est = Recording(np.array(cols["uEst"]), np.array(cols["yEst"]), ts, source, "cascaded_tanks_estimation")
    val = Recording(np.array(cols["uVal"]), np.array(cols["yVal"]), ts, source, "cascaded_tanks_validation")
    return est, val


def brfd_names() -> list[str]:
    """Names of the bundled BRFD tests, e.g. ``"1Hz30lbtension1amplitude"`` (1 Hz sinusoid,
    30 lb band tension, 1 in amplitude), sorted."""
    return sorted(
        entry.name[: -len(".json")]
        for entry in (_DATA / "brfd").iterdir()
        if entry.name.endswith(".json")
    )


def brfd(name: str) -> Recording:
    """One banded rotary friction device test (a semi-active friction damper with backlash).

    Input ``v``: imposed displacement (in, column 1 of the file); output ``y``: friction force
    (kip, column 2); ``dt = 1/1024`` s; `channels` ``"velocity"``, ``"actuator force 1"`` and
    ``"actuator force 2"`` (columns 3-5). Dry friction in the band brake makes the force flat while
    sliding and steep at reversals; backlash in the linkage adds a short flat segment near zero
    force after each reversal.

    **Arguments:**

    - `name`: one of :func:`brfd_names`, e.g. ``"1Hz30lbtension1amplitude"``.

    Data: D. Coble, P. Huggins, L. Cao, J. Ricles, A. Downey, "Dataset-Friction-Damper-with-
    Backlash" (ARTS Lab, 2022), dataset 2, licence CC BY-SA 4.0.
    """
    names = brfd_names()
    if not isinstance(name, str) or name.removesuffix(".json") not in names:
        raise ValueError(f"unknown BRFD record `name` {name!r}; valid names: {', '.join(names)}.")
    return _brfd(name.removesuffix(".json"))


@functools.lru_cache(maxsize=None)
def _brfd(name: str) -> Recording:
    doc = json.loads((_DATA / "brfd" / f"{name}.json").read_text(encoding="utf-8"))
    data = np.asarray(doc["data"], dtype=np.float64)
    channels = {BRFD_COLUMNS[j]: data[:, j] for j in range(3, min(data.shape[1], len(BRFD_COLUMNS)))}
    return Recording(data[:, 1], data[:, 2], float(doc["dt"]), f"hbjax.datasets:brfd:{name}", name,
                     channels=channels)
