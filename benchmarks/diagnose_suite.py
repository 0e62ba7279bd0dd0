"""Accuracy of hbjax.diagnose on recordings from an independent concealed-effect generator
(tests/generators/concealed_effects.py: random base systems, orders, bands, five input
kinds, lengths 1000-8000, noise 0.5-5% of the output spread, effect sizes from just
detectable to strong), which the diagnosis was not tuned on.

For every case the top finding (``Diagnosis.best.effect``, ``None`` when the recording is
consistent with the nominal model) is compared with the concealed effect. Prints overall
and per-effect top-1 accuracy, the findings on clean recordings and a confusion matrix;
exceptions are caught and counted per case.

Run: nice .venv/bin/python benchmarks/diagnose_suite.py --per-effect 3 --clean 6 --seed 0
"""

from __future__ import annotations

import argparse
import collections
import inspect
import json
import os
import re
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import hbjax  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

from generators.concealed_effects import ALL_EFFECTS, concealed_case, random_base  # noqa: E402

NONE = "(none)"


def diagnose_case(case, criterion="prediction"):
    """Run diagnose on one case; channels are passed only if diagnose accepts them."""
    kwargs = {} if criterion == "prediction" else {"criterion": criterion}
    if case["channels"] and "channels" in inspect.signature(hbjax.diagnose).parameters:
        kwargs["channels"] = case["channels"]
    d = hbjax.diagnose(case["nominal_model"], case["v"], case["y"], **kwargs)
    return d


def run(effects, per_effect, clean, seed, nominal="true", n=None, log=print, structures=None,
        only=None, criterion="prediction"):
    """Diagnose the generated cases; with ``only`` (a set of effect names, ``None`` for the
    clean cases) every case is still generated, so the records are those of the full run,
    but only those cases are diagnosed (a before-and-after comparison of a few effects)."""
    rng = np.random.default_rng(seed)
    # Round-robin over the effects, so that a partial run is balanced.
    jobs = [(e, i) for i in range(max(per_effect, clean))
            for e in list(effects) + [None] if i < (clean if e is None else per_effect)]
    records = []
    for k, (effect, i) in enumerate(jobs):
        rec = dict(effect=effect, index=i)
        t0 = time.perf_counter()
        try:
            base = (random_base(rng, **structures[k % len(structures)]) if structures
                    else None)
            case = concealed_case(rng, effect, n=n, nominal=nominal, base=base)
            rec.update(n=len(case["v"]), input_kind=case["input_kind"], size=case["size"],
                       ratio=case["ratio"], orders=[case["base"][x] for x in ("na", "nb", "m")],
                       description=case["description"])
        except Exception as exc:  # noqa: BLE001 - a generator failure is a counted outcome
            rec.update(error=f"generator: {type(exc).__name__}: {exc}")
            records.append(rec)
            log(f"[{k + 1}/{len(jobs)}] {effect}: generator error {exc}")
            continue
        if only is not None and effect not in only:
            continue
        try:
            d = diagnose_case(case, criterion)
            rec["top"] = d.best.effect if d.best is not None else None
            rec["findings"] = [f.effect for f in d.findings]
            # every candidate's criterion, held-out fits, tests and decision, so that a
            # decision rule can be re-evaluated on these records without re-diagnosing
            rec["candidates"] = {
                name: {k: row[k] for k in ("bic", "k", "fit_sim", "fit_pred", "dbic", "dm_z",
                                           "dm_z_simulation", "dm_z_over_constant", "base_p",
                                           "decision") if k in row}
                for name, row in d.candidates.items()}
            rec["n_fit"] = d.n_fit
        except Exception as exc:  # noqa: BLE001
            rec["error"] = f"diagnose: {type(exc).__name__}: {str(exc)[:300]}"
        rec["seconds"] = time.perf_counter() - t0
        records.append(rec)
        log(f"[{k + 1}/{len(jobs)}] {str(effect):26s} -> {str(rec.get('top', 'ERROR')):26s} "
            f"n={rec['n']} {rec['input_kind']} (na,nb,m)={tuple(rec['orders'])} "
            f"ratio={rec['ratio']:.2f} {rec['seconds']:.1f}s")
    return records


def report(records, effects):
    lines = []
    eff_recs = [r for r in records if r["effect"] is not None]
    ok = [r for r in eff_recs if "error" not in r]
    hits = sum(r["top"] == r["effect"] for r in ok)
    errors = [r for r in records if "error" in r]
    lines.append(f"cases: {len(records)} ({len(eff_recs)} with an effect, "
                 f"{len(records) - len(eff_recs)} clean), exceptions: {len(errors)}")
    lines.append(f"overall top-1 accuracy (effect cases, exceptions count as misses): "
                 f"{hits}/{len(eff_recs)} = {100 * hits / max(len(eff_recs), 1):.1f}%")
    lines.append("")
    lines.append(f"{'effect':28s} {'top-1':>9s} {'acc':>6s}  reported instead")
    for e in effects:
        rs = [r for r in eff_recs if r["effect"] == e]
        h = sum(r.get("top") == e for r in rs)
        other = collections.Counter(str(r.get("top", "ERROR")) if "error" not in r else "ERROR"
                                    for r in rs if r.get("top") != e)
        lines.append(f"{e:28s} {h:>4d}/{len(rs):<4d} {100 * h / max(len(rs), 1):5.0f}%  "
                     + ", ".join(f"{k} x{v}" for k, v in other.most_common()))
    clean = [r for r in records if r["effect"] is None]
    if clean:
        with_finding = [r for r in clean if "error" not in r and r["top"] is not None]
        n_findings = [len(r["findings"]) for r in clean if "error" not in r]
        lines.append("")
        lines.append(f"clean recordings: {len(clean)}, with a finding: {len(with_finding)}, "
                     f"findings per recording: max {max(n_findings, default=0)}, "
                     f"total {sum(n_findings)}; reported: "
                     + (", ".join(f"{k} x{v}" for k, v in collections.Counter(
                         r["top"] for r in with_finding).most_common()) or "nothing"))
    lines.append("")
    lines.extend(_breakdowns(ok))
    lines.append("")
    lines.append(_confusion(records, effects))
    if errors:
        lines.append("")
        lines.append("exceptions:")
        for r in errors:
            lines.append(f"  {r['effect']} #{r['index']}: {r['error']}")
    return "\n".join(lines)


def _breakdowns(records):
    """Top-1 accuracy of the effect cases by input kind and by effect size (RMS change of
    the noise-free output over the output noise std, as the generator measured it)."""
    out = []
    rows = [r for r in records if r.get("effect") is not None]
    for title, key, groups in (
            ("input kind", lambda r: r.get("input_kind"), None),
            ("effect size (RMS / output noise std)",
             lambda r: None if r.get("ratio") is None else
             ("< 1.5" if r["ratio"] < 1.5 else "1.5-4" if r["ratio"] < 4 else ">= 4"),
             ("< 1.5", "1.5-4", ">= 4"))):
        seen = collections.defaultdict(list)
        for r in rows:
            k = key(r)
            if k is not None:
                seen[k].append(r.get("top") == r["effect"])
        if not seen:
            continue
        order = groups or sorted(seen)
        out.append(f"by {title}: " + "; ".join(
            f"{k} {sum(seen[k])}/{len(seen[k])} ({100 * sum(seen[k]) / len(seen[k]):.0f}%)"
            for k in order if seen[k]))
    return out


def _confusion(records, effects):
    """Rows: concealed effect; columns: reported top finding (abbreviated, legend below)."""
    truth_rows = list(effects) + [None]
    reported = sorted({r.get("top") for r in records if "error" not in r} - {None},
                      key=lambda x: (list(effects).index(x) if x in effects else len(effects), x))
    cols = reported + [None, "ERROR"]
    abbr = {c: f"{j:>2d}" for j, c in enumerate(cols)}
    counts = collections.Counter(
        (r["effect"], "ERROR" if "error" in r else r["top"]) for r in records)
    out = ["confusion matrix (rows: concealed effect, columns: reported top finding)"]
    out.append(f"{'':28s}" + "".join(f"{abbr[c]:>4s}" for c in cols))
    for t in truth_rows:
        if not any(r["effect"] == t for r in records):
            continue
        row = "".join(f"{(counts[(t, c)] or '.')!s:>4s}" for c in cols)
        out.append(f"{str(t) if t else NONE:28s}{row}")
    out.append("columns: " + "; ".join(f"{abbr[c].strip()} = {c if c is not None else NONE}"
                                       for c in cols))
    return "\n".join(out)


def _records_from_log(path):
    """Per-case records from the ``[k/N] effect -> top ...`` lines of a run's output."""
    pattern = re.compile(r"^\[\d+/\d+\] (\S+)\s+-> (\S+)\s+n=(\d+) (\S+) .*ratio=([\d.]+)")
    records = []
    for line in open(path):
        m = pattern.match(line)
        if m:
            effect, top = (None if x == "None" else x for x in m.groups()[:2])
            rec = dict(effect=effect, index=len(records), n=int(m.group(3)),
                       input_kind=m.group(4), ratio=float(m.group(5)))
            if top == "ERROR":
                rec["error"] = "diagnose (see log)"
            else:
                rec.update(top=top, findings=[top] if top else [])
            records.append(rec)
    return records


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--per-effect", type=int, default=3, help="cases per effect")
    p.add_argument("--clean", type=int, default=6, help="clean cases")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effects", default="all",
                   help="comma-separated effect names, 'all' (default) or 'package' "
                        "(only those in hbjax.EFFECTS)")
    p.add_argument("--nominal", choices=["true", "fitted"], default="true",
                   help="nominal model: the true base system (default) or hbjax.fit on a "
                        "separate clean recording")
    p.add_argument("--n", type=int, default=None, help="fix the record length")
    p.add_argument("--structures", default=None, metavar="NA,NB,M:...",
                   help="cycle through these base structures (orders drawn at random "
                        "otherwise); with --n, compiled code is shared between cases")
    p.add_argument("--diagnose-only", default=None, metavar="EFFECTS",
                   help="comma-separated effect names ('none' for the clean cases): generate "
                        "every case as usual (the same records as the full run) but diagnose "
                        "only these")
    p.add_argument("--criterion", choices=["prediction", "simulation"], default="prediction",
                   help="diagnose's criterion (default: diagnose's own default)")
    p.add_argument("--json", default=None, help="write per-case records and the summary here")
    p.add_argument("--summarise-log", default=None, metavar="FILE",
                   help="no run: rebuild the summary from the per-case lines a (possibly "
                        "interrupted) run printed to FILE")
    args = p.parse_args(argv)
    if args.effects == "all":
        effects = list(ALL_EFFECTS)
    elif args.effects == "package":
        effects = [e for e in ALL_EFFECTS if e in hbjax.EFFECTS]
    else:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    if args.summarise_log:
        records = _records_from_log(args.summarise_log)
        print(f"summary of the {len(records)} cases logged in {args.summarise_log}")
        print(report(records, [e for e in effects if any(r["effect"] == e for r in records)]))
        return
    t0 = time.perf_counter()
    structures = None
    if args.structures:
        structures = [dict(zip(("na", "nb", "m"), map(int, s.split(","))))
                      for s in args.structures.split(":")]
    only = None
    if args.diagnose_only:
        only = {None if e.strip() == "none" else e.strip()
                for e in args.diagnose_only.split(",") if e.strip()}
    records = run(effects, args.per_effect, args.clean, args.seed, args.nominal, args.n,
                  structures=structures, only=only, criterion=args.criterion)
    if only is not None:
        effects = [e for e in effects if e in only]
    text = report(records, effects)
    missing = [e for e in effects if e not in hbjax.EFFECTS]
    print()
    print(f"hbjax.diagnose on the independent generator: seed {args.seed}, {args.per_effect} "
          f"per effect, {args.clean} clean, nominal = {args.nominal}, "
          f"{time.perf_counter() - t0:.0f} s")
    if missing:
        print("effects not (yet) in hbjax.EFFECTS (cannot be named): " + ", ".join(missing))
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(args=vars(args), records=records, summary=text), f, indent=1,
                      default=float)


if __name__ == "__main__":
    main()
