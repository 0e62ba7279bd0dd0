"""What each ``hbjax`` command does (the parser is in :mod:`hbjax._cli.parser`).

Each command imports what it needs (estimators, matplotlib) when it runs, so a command
never pays for another's imports and the numerical core never imports matplotlib.
"""


def cmd_demo(args) -> int:
    from .demo import run_demo

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
    from .._io.recording import load_recording

    return load_recording(path, input=_column_key(args.input), output=_column_key(args.output))


def _read_column(path, key, role):
    """One numeric column of a CSV file; default: the only column, or ``role``'s default."""
    from .._io.recording import read_csv_table

    table = read_csv_table(path)
    if key is None:
        key = 0 if role == "input" or table.n_columns == 1 else 1
    return table.column(table.index(_column_key(key), role))


def _parse_design(text: str):
    from .._core.signals import GiriDesign

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

    from .._core.model import Hammerstein

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


def cmd_signals(args) -> int:
    from .._io.recording import atomic_write, format_float

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


def cmd_simulate(args) -> int:
    import jax
    import jax.numpy as jnp

    from .._io.recording import Recording, save_recording
    from .._io.modelfile import load_model
    from .._core.simulate import simulate

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


def cmd_identify_giri(args) -> int:
    from .._identify.giri import identify_giri
    from .._io.modelfile import save_model

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


MONTE_CARLO_KEYS = {
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

    from .._core.defaults import default_design, default_system
    from .._core.model import Hammerstein
    from .._io.modelfile import load_model
    from .._core.signals import GiriDesign

    config = _read_json(path, "config file")
    if not isinstance(config, dict):
        raise ValueError(f"{path}: the config must be a JSON object with keys {sorted(MONTE_CARLO_KEYS)}.")
    unknown = sorted(set(config) - set(MONTE_CARLO_KEYS))
    if unknown:
        raise ValueError(f"{path}: unknown config keys {unknown}; valid keys: {sorted(MONTE_CARLO_KEYS)}.")
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


def cmd_montecarlo(args) -> int:
    import dataclasses
    import os

    import jax

    from .. import __version__
    from .._io.recording import atomic_write
    from .._io.modelfile import pretty_json
    from .._montecarlo.run import monte_carlo

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
    from .._io.recording import atomic_write

    atomic_write(path, buf.getvalue(), overwrite=overwrite)
    print(f"wrote {path}")


def cmd_diagnose(args) -> int:
    import os

    from .. import __version__
    from .._diagnose.diagnose import diagnose
    from .._io.recording import atomic_write
    from .._core.model import Hammerstein
    from .._io.modelfile import load_model, pretty_json, save_model

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
    options = {} if args.criterion is None else {"criterion": args.criterion}
    report = diagnose(model, rec.v, rec.y, holdout=args.holdout, effects=effects, **options)
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

        from .._plot.diagnosis import plot_diagnosis

        fig, axes = plt.subplots(3, 1, figsize=(9, 9), layout="constrained")
        plot_diagnosis(report, axes=axes)
        _write_figure(args.plot, fig, overwrite=args.force)
    return 0


def cmd_identify_fit(args) -> int:
    import os

    import jax
    import numpy as np

    from .._identify.fit import fit
    from .._io.modelfile import save_model

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


def cmd_show(args) -> int:
    from .._io.modelfile import load_model

    model = load_model(args.model)
    print(f"{args.model}: {type(model).__name__}")
    print(_describe_model(model))
    return 0
