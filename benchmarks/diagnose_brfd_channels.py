"""Missing input on real data: the BRFD friction damper's actuator channels.

The banded rotary friction device's friction force (output) follows the normal force the
actuators press the band with; the HB-Hammerstein model sees only the imposed displacement.
For every characterisation test (``hbjax.datasets.brfd``), decimated by 8 (block means,
128 Hz) and cut to its first ``--n`` samples, the nominal model identified on the 1 Hz /
30 lb / 1 in test (as notebook 04 does) is diagnosed three ways: without channels, with the
two actuator forces, and with every channel (velocity too). Prints the verdict, the best
finding, the channels it names and the held-out free-run fit before and after.

Run: nice .venv/bin/python benchmarks/diagnose_brfd_channels.py
"""

from __future__ import annotations

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import hbjax  # noqa: E402

REF = "1Hz30lbtension1amplitude"
ACTUATORS = ("actuator force 1", "actuator force 2")


def decimated(name, n, k=8):
    """Input, output and channels of one test, block means of ``k`` samples, first ``n``."""
    r = hbjax.datasets.brfd(name)
    m = len(r.v) // k * k

    def dec(x):
        return np.asarray(x)[:m].reshape(-1, k).mean(1)[:n]

    return dec(r.v), dec(r.y), {c: dec(w) for c, w in r.channels.items()}


def nominal(n):
    v0, y0, _ = decimated(REF, n)
    return hbjax.identify_nominal(v0, y0, na=1, nb=1, m=2, gap=0.05, criterion="simulation",
                                  transient=20)


def run(n=896, criterion="simulation", log=print):
    model = nominal(n)
    rows = []
    for name in hbjax.datasets.brfd_names():
        v, y, channels = decimated(name, n)
        for label, offered in (("none", None),
                               ("actuators", {c: channels[c] for c in ACTUATORS}),
                               ("all", channels)):
            t0 = time.perf_counter()
            d = hbjax.diagnose(model, v, y, criterion=criterion, channels=offered, progress=False)
            f = d.best
            mi = next((x for x in d.findings if x.effect == "missing_input"), None)
            row = dict(test=name, channels=label, verdict=d.verdict,
                       best=f.effect if f else None,
                       fit_before=f.fit_before if f else None,
                       fit_after=f.fit_after if f else None,
                       missing_input=(mi.parameters["channels"] if mi else None),
                       mi_gain=(mi.fit_after - mi.fit_before) if mi else None,
                       n_holdout=d.n_holdout, moved=d.split.get("moved"),
                       seconds=time.perf_counter() - t0)
            rows.append(row)
            log(f"{name:28s} channels={label:9s} verdict={d.verdict:11s} "
                f"best={str(row['best']):20s} "
                + (f"fit {f.fit_before:6.1f}% -> {f.fit_after:6.1f}%" if f else "")
                + (f"  missing_input {mi.parameters['channels']} variant "
                   f"{mi.parameters['variant']} +{row['mi_gain']:.1f} pts" if mi else "")
                + f"  held out {d.n_holdout}{' (moved)' if row['moved'] else ''}"
                  f"  {row['seconds']:.0f}s")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=896, help="samples per test after decimation")
    p.add_argument("--criterion", default="simulation", choices=["simulation", "prediction"])
    args = p.parse_args(argv)
    rows = run(args.n, args.criterion)
    act = [r for r in rows if r["channels"] == "actuators"]
    named = sum(r["missing_input"] is not None
                and set(r["missing_input"]) & set(ACTUATORS) != set() for r in act)
    gains = [r["mi_gain"] for r in act if r["mi_gain"] is not None]
    print(f"\nactuator channels offered: missing_input naming them on {named}/{len(act)} tests; "
          f"held-out free-run gain {', '.join(f'{g:.1f}' for g in gains)} points")


if __name__ == "__main__":
    main()
