"""Command-line interface: ``hbjax <command>`` and ``python -m hbjax <command>``.

Every command has ``--help`` with an example. Errors print one line on stderr and exit with
status 1 (``--debug`` shows the traceback instead); usage errors exit with status 2. Output
files are never overwritten unless ``--force`` is given, and are written atomically.
"""

import argparse
import sys

_EPILOG_RECORDINGS = (
    "recording files: CSV with a header row; by default the first column is the input v and "
    "the second the output y; --input NAME / --output NAME select columns by header name "
    "(or 0-based index)."
)


def _cmd_demo(args) -> int:
    from ._demo import run_demo

    run_demo(args.out, force=args.force, n_samples=args.samples, seed=args.seed)
    return 0


# ----------------------------------------------------------------------------- helpers


def _column_key(key):
    """A ``--input``/``--output`` value: an int if it is one, else a header name."""
    if key is None:
        return None
    text = str(key).strip()
    return int(text) if text.lstrip("-").isdigit() else text


def _read_recording(path, args):
    from ._io import load_recording

    return load_recording(path, input=_column_key(args.input), output=_column_key(args.output))


def _read_column(path, key, role):
    """One numeric column of a CSV file; default: the only column, or ``role``'s default."""
    from ._io import read_csv_table

    table = read_csv_table(path)
    if key is None:
        key = 0 if role == "input" or table.n_columns == 1 else 1
    return table.column(table.index(_column_key(key), role))


def _parse_design(text: str):
    from ._signals import GiriDesign

    parts = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--design must look like n=2,m=3,h_m=4, got {text!r}.")
        parts[name.strip()] = value.strip()
    if set(parts) != {"n", "m", "h_m"}:
        raise ValueError(f"--design needs exactly n, m and h_m (e.g. n=2,m=3,h_m=4), got {text!r}.")
    try:
        return GiriDesign(int(parts["n"]), int(parts["m"]), float(parts["h_m"]))
    except ValueError as exc:
        raise ValueError(f"--design {text!r}: {exc}") from None


def _describe_model(model, indent: str = "  ") -> str:
    """Parameters of a model: the Hammerstein blocks by name, other fields generically."""
    import dataclasses

    import jax
    import numpy as np

    from ._model import Hammerstein

    def fmt(x):
        return np.array2string(np.asarray(x), precision=6, separator=", ")

    if isinstance(model, Hammerstein):
        return (
            f"{indent}a  = {fmt(model.arx.a)}\n{indent}b  = {fmt(model.arx.b)}\n"
            f"{indent}c1 = {fmt(model.backlash.c1)}  (P1, ascending powers)\n"
            f"{indent}c2 = {fmt(model.backlash.c2)}  (P2, ascending powers)"
        )
    lines = []
    for f in dataclasses.fields(model):
        value = getattr(model, f.name)
        if isinstance(value, Hammerstein):
            lines.append(f"{indent}{f.name}: Hammerstein")
            lines.append(_describe_model(value, indent + "  "))
        elif isinstance(value, (jax.Array, np.ndarray)):
            lines.append(f"{indent}{f.name} = {fmt(value)}")
        else:
            lines.append(f"{indent}{f.name} = {value!r}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- commands


def _cmd_signals(args) -> int:
    from ._io import atomic_write, format_float

    design = _parse_design(args.design)
    signals = (
        design.constant_input(args.samples),
        design.binary_input(args.samples),
        design.staircase_input(args.samples),
    )
    written = []
    for k, v in enumerate(signals, start=1):
        text = "v\n" + "".join(format_float(x) + "\n" for x in v)
        written.append(atomic_write(f"{args.prefix}{k}.csv", text, overwrite=args.force))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _cmd_simulate(args) -> int:
    import jax
    import jax.numpy as jnp

    from ._io import Recording, save_recording
    from ._modelfile import load_model
    from ._simulate import simulate

    model = load_model(args.model)
    v = _read_column(args.input, args.column, "input")
    if args.noise_std < 0:
        raise ValueError(f"--noise-std must be >= 0, got {args.noise_std}.")
    noise = None
    if args.noise_std > 0:
        noise = args.noise_std * jax.random.normal(jax.random.PRNGKey(args.seed), v.shape, jnp.float64)
    y = simulate(model, v, noise, u0=args.u0)
    save_recording(args.out, Recording(v, jax.device_get(y)), overwrite=args.force)
    print(f"wrote {args.out}: {v.shape[0]} samples (columns v, y)")
    return 0


def _cmd_identify_giri(args) -> int:
    from ._giri import identify_giri
    from ._modelfile import save_model

    design = _parse_design(args.design)
    ys = [_read_column(path, args.output, "output") for path in args.records]
    result = identify_giri(design, *ys, transient=args.transient)
    save_model(args.out, result.model, overwrite=args.force)
    print(f"identified the normalised model (paper section 4.1), design {args.design}:")
    print(_describe_model(result.model))
    print(
        f"  offset = {float(result.offset):.6g} (transient {int(result.transient)} samples "
        f"discarded), noise std = {float(result.noise_std):.4g}, "
        f"cond(LS) = {float(result.cond_ls):.3g}"
    )
    print(f"wrote {args.out}")
    return 0


_MC_KEYS = {
    "model": "a model file (path relative to the config) or \"default\" (hbjax.default_system())",
    "design": "\"n=2,m=3,h_m=4\" or {\"n\": 2, \"m\": 3, \"h_m\": 4} (default: hbjax.default_design())",
    "noise_std": "standard deviation of the noise (required)",
    "lengths": "record lengths per experiment, a list (required)",
    "realisations": "noise realisations per length (required)",
    "seed": "PRNG seed (default 0)",
    "estimator": "\"giri\" or \"refined\" (default \"giri\")",
    "noise": "\"equation\" or \"output\" (default \"equation\")",
    "chunk_size": "realisations per device per chunk (default: automatic)",
    "keep_estimates": "keep every estimate, for the histograms (default false)",
}


def _read_json(path, what):
    import json
    import pathlib

    p = pathlib.Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} {str(p)!r} does not exist.")
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not valid JSON ({exc}).") from None


def _study_config(path):
    import pathlib

    from ._defaults import default_design, default_system
    from ._model import Hammerstein
    from ._modelfile import load_model
    from ._signals import GiriDesign

    config = _read_json(path, "config file")
    if not isinstance(config, dict):
        raise ValueError(f"{path}: the config must be a JSON object with keys {sorted(_MC_KEYS)}.")
    unknown = sorted(set(config) - set(_MC_KEYS))
    if unknown:
        raise ValueError(f"{path}: unknown config keys {unknown}; valid keys: {sorted(_MC_KEYS)}.")
    missing = [k for k in ("noise_std", "lengths", "realisations") if k not in config]
    if missing:
        raise ValueError(f"{path}: missing config keys {missing} (see hbjax montecarlo --help).")
    model_ref = config.get("model", "default")
    if model_ref == "default":
        model = default_system()
    elif isinstance(model_ref, str):
        model = load_model(pathlib.Path(path).parent / model_ref)
    else:
        raise ValueError(f"{path}: `model` must be a model-file path or \"default\".")
    if not isinstance(model, Hammerstein):
        raise ValueError(f"{path}: the Monte Carlo study needs an hbjax.Hammerstein model, got "
                         f"{type(model).__name__}.")
    design = config.get("design")
    if design is None:
        design = default_design()
    elif isinstance(design, str):
        design = _parse_design(design)
    elif isinstance(design, dict) and set(design) == {"n", "m", "h_m"}:
        design = GiriDesign(design["n"], design["m"], design["h_m"])
    else:
        raise ValueError(f"{path}: `design` must be \"n=2,m=3,h_m=4\" or an object with n, m, h_m.")
    lengths = config["lengths"]
    if not isinstance(lengths, list) or not lengths:
        raise ValueError(f"{path}: `lengths` must be a non-empty list of integers.")
    for key in ("seed", "realisations"):
        value = config.get(key, 0)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{path}: `{key}` must be an integer, got {value!r}.")
    return model, design, config


def _jsonable(value):
    """Arrays to nested lists with NaN/inf as null, numpy scalars to Python numbers."""
    import math

    import numpy as np

    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_jsonable(x) for x in value]
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _cmd_montecarlo(args) -> int:
    import dataclasses
    import os

    import jax

    from . import __version__
    from ._io import atomic_write
    from ._modelfile import pretty_json
    from ._monte_carlo import monte_carlo

    for out in (args.out, args.plot):
        if out is not None and os.path.abspath(out) == os.path.abspath(args.config):
            raise ValueError(f"the output {out!r} would replace the config file; choose another name.")
    for out in (args.out, args.plot):  # fail before a long study, not after it
        if out is not None and os.path.exists(out) and not args.force:
            raise FileExistsError(f"{out!r} already exists; pass --force to replace it.")
    model, design, config = _study_config(args.config)
    study = monte_carlo(
        model, design,
        noise_std=config["noise_std"], lengths=config["lengths"],
        realisations=config["realisations"], key=jax.random.key(config.get("seed", 0)),
        estimator=config.get("estimator", "giri"), noise=config.get("noise", "equation"),
        chunk_size=config.get("chunk_size"), progress=not args.no_progress,
        keep_estimates=bool(config.get("keep_estimates", False)) or args.plot is not None,
    )
    study.table()
    fields = {f.name: _jsonable(getattr(study, f.name)) for f in dataclasses.fields(study)}
    if not config.get("keep_estimates", False):
        fields["estimates"] = None
    doc = {"format": "hbjax-study", "hbjax_version": __version__, "config": config,
           "design": {"n": design.n, "m": design.m, "h_m": design.h_m}, "study": fields}
    atomic_write(args.out, pretty_json(doc) + "\n", overwrite=args.force)
    print(f"wrote {args.out}")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        _write_figure(args.plot, study.plot(), overwrite=args.force)
    return 0


def _write_figure(path, fig, *, overwrite):
    import io
    import os

    buf = io.BytesIO()
    fig.savefig(buf, format=os.path.splitext(path)[1].lstrip(".") or "png", dpi=120)
    from ._io import atomic_write

    atomic_write(path, buf.getvalue(), overwrite=overwrite)
    print(f"wrote {path}")


def _cmd_diagnose(args) -> int:
    import os

    from . import __version__
    from ._diagnose import diagnose
    from ._io import atomic_write
    from ._model import Hammerstein
    from ._modelfile import load_model, pretty_json, save_model

    for out in (args.json, args.plot, args.save_model):  # refuse before the long part
        if out is not None and os.path.exists(out) and not args.force:
            raise FileExistsError(f"{out!r} already exists; pass --force to replace it.")
    model = load_model(args.model)
    if not isinstance(model, Hammerstein):
        raise ValueError(f"{args.model}: diagnose needs the nominal hbjax.Hammerstein model, "
                         f"got {type(model).__name__}.")
    rec = _read_recording(args.recording, args)
    effects = None
    if args.effects:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    report = diagnose(model, rec.v, rec.y, holdout=args.holdout, effects=effects)
    print(f"{rec.source}: {len(rec)} samples, nominal model {args.model}")
    print(report.summary())
    if args.json is not None:
        doc = {"format": "hbjax-diagnosis", "hbjax_version": __version__,
               "model": args.model, "recording": rec.source, "report": report.to_dict()}
        atomic_write(args.json, pretty_json(doc) + "\n", overwrite=args.force)
        print(f"wrote {args.json}")
    if args.save_model is not None:
        if report.best is None:
            print(f"no finding: {args.save_model} not written")
        else:
            save_model(args.save_model, report.best.model, overwrite=args.force)
            print(f"wrote {args.save_model} ({type(report.best.model).__name__})")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from ._plot_diagnosis import plot_diagnosis

        fig, axes = plt.subplots(3, 1, figsize=(9, 9), layout="constrained")
        plot_diagnosis(report, axes=axes)
        _write_figure(args.plot, fig, overwrite=args.force)
    return 0


def _cmd_identify_fit(args) -> int:
    import os

    import jax
    import numpy as np

    from ._fit import fit
    from ._modelfile import save_model

    if os.path.exists(args.out) and not args.force:  # refuse before the long part
        raise FileExistsError(f"{args.out!r} already exists; pass --force to replace it.")
    records = [_read_recording(path, args) for path in args.records]
    options = {} if args.max_steps is None else {"max_steps": args.max_steps}
    result = fit(
        [(r.v, r.y) for r in records], na=args.na, nb=args.nb, m=args.m,
        key=jax.random.key(args.seed), starts=args.starts, criterion=args.criterion, **options,
    )
    save_model(args.out, result.model, overwrite=args.force)
    samples = sum(len(r) for r in records)
    print(f"identified (na, nb, m) = ({args.na}, {args.nb}, {args.m}) from {len(records)} "
          f"recording(s), {samples} samples; normalisation B(1) = 1:")
    print(_describe_model(result.model))
    std = np.asarray(result.std)
    print(f"  standard errors (a, b, c1, c2) = {np.array2string(std, precision=3, separator=', ')}")
    print(f"  noise std = {float(result.noise_std):.4g}; {args.starts} starts, "
          f"{float(result.hit_rate):.0%} reached the best cost; {result.message}")
    print(f"wrote {args.out}")
    return 0


def _cmd_show(args) -> int:
    from ._modelfile import load_model

    model = load_model(args.model)
    print(f"{args.model}: {type(model).__name__}")
    print(_describe_model(model))
    return 0


# ----------------------------------------------------------------------------- parser


class _Formatter(argparse.HelpFormatter):
    """Wraps each paragraph of a description on its own; indented lines (examples) stay."""

    def _fill_text(self, text, width, indent):
        out = []
        for para in text.split("\n\n"):
            if para.startswith("  "):
                out.append("\n".join(indent + line for line in para.splitlines()))
            else:
                out.append(super()._fill_text(para, width, indent))
        return "\n\n".join(out)


def _add_command(sub, name, *, help, description, example, parents=()):
    examples = example if isinstance(example, (list, tuple)) else [example]
    label = "example" if len(examples) == 1 else "examples"
    return sub.add_parser(
        name,
        help=help,
        description=description,
        epilog=f"{label}:\n\n" + "\n".join(f"  {e}" for e in examples),
        parents=list(parents),
        formatter_class=_Formatter,
    )


def build_parser() -> argparse.ArgumentParser:
    # --debug is accepted before or after the command name.
    debug = argparse.ArgumentParser(add_help=False)
    debug.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show the traceback on error")
    parser = argparse.ArgumentParser(
        prog="hbjax",
        description="Identify Hammerstein systems with hysteresis-backlash input nonlinearity.",
        epilog="example:\n\n  hbjax demo --out demo_output\n\n"
        "Run `hbjax COMMAND --help` for the options and an example of each command.",
        formatter_class=_Formatter,
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on error")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = _add_command(
        sub, "demo", parents=[debug],
        help="simulate the default system, run the paper's three experiments, identify it",
        description="The main job on the embedded default system.",
        example="hbjax demo --out demo_output",
    )
    demo.add_argument("--out", default="demo_output", help="folder for the figures and table")
    demo.add_argument("--force", action="store_true", help="overwrite files in --out")
    demo.add_argument("--samples", type=int, default=10_000, help="samples per experiment")
    demo.add_argument("--seed", type=int, default=0, help="PRNG seed of the noise")
    demo.set_defaults(func=_cmd_demo)

    signals = _add_command(
        sub, "signals", parents=[debug],
        help="write the paper's three excitation inputs v1, v2, v3 as CSV files",
        description="Write v1 (eq. 14), v2 (eq. 27) and v3 (eq. 32) for a design to "
        "PREFIX1.csv, PREFIX2.csv, PREFIX3.csv (one column `v`).",
        example="hbjax signals --design n=2,m=3,h_m=4 --samples 2000 --prefix v",
    )
    signals.add_argument("--design", required=True, help="n=ORDER,m=COEFFS,h_m=AMPLITUDE")
    signals.add_argument("--samples", type=int, required=True, help="samples per signal")
    signals.add_argument("--prefix", default="v", help="file name prefix (default: v)")
    signals.add_argument("--force", action="store_true", help="overwrite existing files")
    signals.set_defaults(func=_cmd_signals)

    simulate = _add_command(
        sub, "simulate", parents=[debug],
        help="simulate a saved model on an input recording",
        description="Free-run simulation (paper eq. (10)) of a model file on the input column "
        "of a CSV file; writes a CSV with columns v, y.\n\n"
        "--noise-std adds white Gaussian equation error xi(t) (eq. (10)) drawn with --seed.",
        example="hbjax simulate --model model.json --input v.csv --out y.csv --noise-std 0.5 --seed 1",
    )
    simulate.add_argument("--model", required=True, help="model file (hbjax save_model JSON)")
    simulate.add_argument("--input", required=True, help="CSV file with the input signal")
    simulate.add_argument("--column", default=None,
                          help="input column (header name or index; default: the first)")
    simulate.add_argument("--out", required=True, help="CSV file to write (columns v, y)")
    simulate.add_argument("--noise-std", type=float, default=0.0, help="std of xi(t) (default 0)")
    simulate.add_argument("--seed", type=int, default=0, help="PRNG seed of the noise")
    simulate.add_argument("--u0", type=float, default=0.0, help="initial backlash output u(-1)")
    simulate.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    simulate.set_defaults(func=_cmd_simulate)

    identify = _add_command(
        sub, "identify", parents=[debug],
        help="identify a model from recordings",
        description="Identification methods: `giri` (the paper's closed form on its three "
        "experiments) and `fit` (multi-start prediction-error fit on any recordings).",
        example="hbjax identify giri --design n=2,m=3,h_m=4 y1.csv y2.csv y3.csv --out model.json",
    )
    methods = identify.add_subparsers(dest="method", required=True, metavar="METHOD")
    giri = _add_command(
        methods, "giri", parents=[debug],
        help="the paper's closed-form identification from its three experiments",
        description="Identify the normalised HB-Hammerstein model (paper section 4) from the "
        "outputs y1, y2, y3 of the experiments v1 (eq. 14), v2 (eq. 27), v3 (eq. 32).\n\n"
        "Each record is a CSV file; its output column is --output, by default the second "
        "column (or the only one).",
        example="hbjax identify giri --design n=2,m=3,h_m=4 y1.csv y2.csv y3.csv --out model.json",
    )
    giri.add_argument("--design", required=True, help="n=ORDER,m=COEFFS,h_m=AMPLITUDE")
    giri.add_argument("records", nargs=3, metavar="Yk.csv",
                      help="three CSV files: outputs of v1, v2, v3 (in this order)")
    giri.add_argument("--output", default=None, help="output column (header name or index)")
    giri.add_argument("--transient", type=int, default=None,
                      help="samples of y1 to discard (default: settling time of A)")
    giri.add_argument("--out", required=True, help="model file to write (JSON)")
    giri.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    giri.set_defaults(func=_cmd_identify_giri)

    mc_keys = "\n".join(f"  {k:<15} {v}" for k, v in _MC_KEYS.items())
    mc = _add_command(
        sub, "montecarlo", parents=[debug],
        help="Monte Carlo study of the closed-form estimator (bias, std, RMSE vs N)",
        description="Run hbjax.monte_carlo on the paper's three experiments: for every record "
        "length and noise realisation simulate, identify and compare with the normalised "
        "truth. Prints the table, writes the statistics as JSON (NaN as null) and optionally "
        "the RMSE-vs-N figure. A progress bar runs on stderr.\n\n"
        "The config file is a JSON object with the keys:\n\n" + mc_keys + "\n\n"
        "For instance:\n\n"
        '  {"model": "default", "design": "n=2,m=3,h_m=4", "noise_std": 0.5,\n'
        '   "lengths": [1000, 4000, 16000], "realisations": 200, "seed": 0}',
        example="hbjax montecarlo --config study_config.json --out study.json --plot study.png",
    )
    mc.add_argument("--config", required=True, help="study configuration (JSON, keys above)")
    mc.add_argument("--out", required=True, help="JSON file for the study's statistics")
    mc.add_argument("--plot", default=None, help="figure file (.png, .pdf, .svg)")
    mc.add_argument("--no-progress", action="store_true", help="no progress bar")
    mc.add_argument("--force", action="store_true", help="overwrite --out/--plot if they exist")
    mc.set_defaults(func=_cmd_montecarlo)

    diag = _add_command(
        sub, "diagnose", parents=[debug],
        help="what does the nominal model leave out of a recording? (hbjax.diagnose)",
        description="Compare a recording of the real system with the nominal model, locate "
        "and name the structured mismatch (saturations, delays, drifts, unmodelled dynamics, "
        "...) and print the readable report; optionally write it as JSON, plot it and save "
        "the extended model of the best finding as a model file.\n\n" + _EPILOG_RECORDINGS,
        example="hbjax diagnose --model model.json rec.csv --json report.json --plot report.png",
    )
    diag.add_argument("--model", required=True, help="nominal model file (a Hammerstein)")
    diag.add_argument("recording", help="CSV recording of the real system")
    diag.add_argument("--input", default=None, help="input column (default: the first)")
    diag.add_argument("--output", default=None, help="output column (default: the second)")
    diag.add_argument("--holdout", type=float, default=0.3,
                      help="final fraction of the record kept out of every fit (default 0.3)")
    diag.add_argument("--effects", default=None,
                      help="comma-separated effect names to consider (default: all)")
    diag.add_argument("--json", default=None, help="write the report as JSON")
    diag.add_argument("--plot", default=None, help="write the report figure (.png, .pdf, .svg)")
    diag.add_argument("--save-model", default=None,
                      help="write the extended model of the best finding (model file)")
    diag.add_argument("--force", action="store_true", help="overwrite output files")
    diag.set_defaults(func=_cmd_diagnose)

    fitp = _add_command(
        methods, "fit", parents=[debug],
        help="multi-start prediction-error fit on ordinary recordings (hbjax.fit)",
        description="Identify an HB-Hammerstein model of orders (na, nb, m) from one or more "
        "recordings with any input (steps, multisines, random levels), by multi-start "
        "Levenberg-Marquardt; the model is normalised so that B(1) = 1.\n\n"
        + _EPILOG_RECORDINGS,
        example=[
            "hbjax identify fit --na 2 --nb 2 --m 3 rec.csv --out model.json",
            "hbjax identify fit --na 2 --nb 2 --m 3 a.csv b.csv --input drive --output level "
            "--starts 64 --out model.json",
        ],
    )
    fitp.add_argument("records", nargs="+", metavar="REC.csv", help="recordings (input, output)")
    fitp.add_argument("--na", type=int, required=True, help="order of A")
    fitp.add_argument("--nb", type=int, required=True, help="order of B")
    fitp.add_argument("--m", type=int, required=True, help="coefficients per branch (degree + 1)")
    fitp.add_argument("--input", default=None, help="input column (default: the first)")
    fitp.add_argument("--output", default=None, help="output column (default: the second)")
    fitp.add_argument("--starts", type=int, default=32, help="random starts (default 32)")
    fitp.add_argument("--seed", type=int, default=0, help="PRNG seed of the starts")
    fitp.add_argument("--criterion", choices=("prediction", "simulation"), default="prediction",
                      help="one-step prediction error (default) or free-run simulation error")
    fitp.add_argument("--max-steps", type=int, default=None,
                      help="Levenberg-Marquardt steps per start (default: hbjax.fit's)")
    fitp.add_argument("--out", required=True, help="model file to write (JSON)")
    fitp.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    fitp.set_defaults(func=_cmd_identify_fit)

    show = _add_command(
        sub, "show", parents=[debug],
        help="print the parameters of a model file",
        description="Load a model file and print its kind and parameters.",
        example="hbjax show model.json",
    )
    show.add_argument("model", help="model file")
    show.set_defaults(func=_cmd_show)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print(f"hbjax {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one clear line unless --debug
        if getattr(args, "debug", False):
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"hbjax {args.command}: error: {message}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
