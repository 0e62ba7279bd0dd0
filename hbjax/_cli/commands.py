"""What each ``hbjax`` command does (the parser is in :mod:`hbjax._cli.parser`).

Each command imports what it needs (estimators, matplotlib) when it runs, so a command
never pays for another's imports and the numerical core never imports matplotlib.
"""


def cmd_demo(args) -> int:
    from .demo import run_demo

    run_demo(args.out, force=args.force, n_samples=args.n_samples, seed=args.seed)
    return 0


# ----------------------------------------------------------------------------- helpers

SEED_LIMIT = 2**63  # JAX's keys and NumPy's generators take seeds in [0, 2**63)


def _significant(x, digits: int) -> str:
    """``[x0, x1, ...]`` with `digits` significant digits each: a small nonzero value (a
    standard error of 4.7e-4) never prints as ``0.`` as a fixed number of decimals would."""
    import numpy as np

    return "[" + ", ".join(f"{float(e):.{digits}g}" for e in np.ravel(np.asarray(x))) + "]"


def _column_key(key):
    """A ``--input``/``--output`` value: an int if it is one, else a header name."""
    if key is None:
        return None
    text = str(key).strip()
    return int(text) if text.lstrip("-").isdigit() else text


def _read_recording(path, args):
    from .._io.recording import load_recording

    return load_recording(path, input=_column_key(args.input), output=_column_key(args.output))


def _read_column(path, key, role, *, with_dt=False):
    """One numeric column of a CSV file; default: the only column, or ``role``'s default
    (``v``/``y`` by name in the layout hbjax writes, else the first/second column).
    ``with_dt``: also the file's sampling period (``None`` when it does not say)."""
    from .._io.files import check_readable
    from .._io.csvtable import read_csv_table

    table = read_csv_table(check_readable(path, f"{role} file"))
    if key is None:
        v_col, y_col = table.default_columns()
        key = 0 if table.n_columns == 1 else (v_col if role == "input" else y_col)
    column = table.column(table.index(_column_key(key), role))
    return (column, table.dt) if with_dt else column


def _read_giri_record(path, args):
    """The output ``y`` of one of ``identify giri``'s records and its recorded input ``v``
    (``None`` when the file has no input column), with a label of that column for messages.

    Columns: ``--output``, by default the only column or ``y`` by name in the layout hbjax
    writes, else the second; ``--input``, by default ``v`` by name, else the first column of
    a file with two or more."""
    from .._io.files import check_readable
    from .._io.csvtable import read_csv_table

    table = read_csv_table(check_readable(path, "output file"))
    v_col, y_col = table.default_columns()
    one = table.n_columns == 1
    j_y = table.index(_column_key(args.output), "output") if args.output is not None else (
        0 if one else y_col)
    j_v = table.index(_column_key(args.input), "input") if args.input is not None else (
        None if one else v_col)
    if j_v == j_y:
        if args.input is not None:
            raise ValueError(f"{path}: --input and --output name the same column "
                             f"({table.column_label(j_y)}).")
        j_v = None  # --output took the default input column: the file records no input
    v = None if j_v is None else table.column(j_v)
    return v, table.column(j_y), None if j_v is None else table.column_label(j_v)


FIGURE_HINT = "(.png, .pdf, .svg, ...)"


def _check_outputs(args, outputs, inputs=(), figures=()):
    """Refuse, before any work, every output that cannot be written: ``outputs`` maps option
    (``--out``) to path (None: not asked for); ``inputs`` are files the command reads, which
    no output may replace; ``figures`` the options whose suffix must be a figure format."""
    import os

    from .._io.files import check_writable

    if not isinstance(inputs, dict):
        inputs = {f"the input file {str(p)!r}": p for p in inputs}
    seen = {}
    for option, path in outputs.items():
        if path is None:
            continue
        real = os.path.realpath(path)
        for what, inp in inputs.items():
            if inp is not None and os.path.realpath(inp) == real:
                raise ValueError(f"{option} {str(path)!r} would replace {what}; choose another "
                                 "name.")
        try:
            check_writable(path, overwrite=args.force, hint="--force")
        except (OSError, ValueError) as exc:
            raise type(exc)(f"{option}: {exc}") from None
        special = os.path.exists(path) and not os.path.isfile(path)
        if real in seen and not special:
            raise ValueError(f"{seen[real]} and {option} name the same file {str(path)!r}; "
                             "choose different names.")
        seen[real] = option
        if option in figures:
            _figure_format(path, option)


def _figure_format(path, option) -> str:
    import os

    from matplotlib.backend_bases import FigureCanvasBase

    fmt = os.path.splitext(str(path))[1].lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if fmt not in formats:
        raise ValueError(f"{option} {str(path)!r}: unsupported figure format {fmt or '(none)'!r}; "
                         f"use one of {', '.join('.' + f for f in sorted(formats))}.")
    return fmt


def _figure_bytes(fig, path) -> bytes:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=_figure_format(path, "figure"), dpi=120)
    return buf.getvalue()


def _write_all(args, items):
    """Publish every ``(path, data)`` together (all or nothing) and say so."""
    from .._io.files import atomic_write_many

    for p in atomic_write_many(items, overwrite=args.force, hint="--force"):
        print(f"wrote {p}")


def _parse_design(text: str):
    from .._core.signals import GiriDesign

    parts = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--design must look like n=2,m=3,h_m=4, got {text!r}.")
        if name.strip() in parts:  # never let a later value silently win
            raise ValueError(f"--design gives {name.strip()!r} twice, in {text!r}.")
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
        return _significant(x, 6)

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
    from .._io.recording import format_float
    from .._misc import positive_int

    design = _parse_design(args.design)
    # every signal needs one period of its own (the staircase's is the longest): checked
    # under the option's name before anything is written
    positive_int(args.samples, "samples",
                 minimum=max(design.binary_period, design.staircase_period))
    paths = [f"{args.prefix}{k}.csv" for k in (1, 2, 3)]
    _check_outputs(args, {f"--prefix ({p})": p for p in paths})
    signals = (
        design.constant_input(args.samples),
        design.binary_input(args.samples),
        design.staircase_input(args.samples),
    )
    texts = ["v\n" + "".join(format_float(x) + "\n" for x in v) for v in signals]
    _write_all(args, list(zip(paths, texts)))
    return 0


def cmd_simulate(args) -> int:
    import jax
    import jax.numpy as jnp

    from .._io.recording import Recording, save_recording
    from .._io.modelfile import load_model
    from .._core.simulate import simulate

    import math

    if not (math.isfinite(args.noise_std) and args.noise_std >= 0):
        raise ValueError(f"--noise-std must be a finite number >= 0, got {args.noise_std}.")
    if not math.isfinite(args.u0):
        raise ValueError(f"--u0 must be a finite number, got {args.u0}.")
    _check_outputs(args, {"--out": args.out}, inputs=[args.model, args.input])
    model = load_model(args.model)
    v, dt = _read_column(args.input, args.column, "input", with_dt=True)
    noise = None
    if args.noise_std > 0:
        noise = args.noise_std * jax.random.normal(jax.random.PRNGKey(args.seed), v.shape, jnp.float64)
    y = simulate(model, v, noise, u0=args.u0)
    save_recording(args.out, Recording(v, jax.device_get(y), dt=dt), overwrite=args.force)
    print(f"wrote {args.out}: {v.shape[0]} samples (columns v, y)")
    return 0


def cmd_identify_giri(args) -> int:
    from .._identify.giri import identify_giri
    from .._io.modelfile import save_model

    design = _parse_design(args.design)
    _check_outputs(args, {"--out": args.out}, inputs=args.records)
    records = [_read_giri_record(path, args) for path in args.records]
    ys = [y for _, y, _ in records]
    inputs = {f"v{k}": v for k, (v, _, _) in enumerate(records, 1)}
    try:  # the recorded inputs are checked against --design
        result = identify_giri(design, *ys, **inputs, transient=args.transient)
    except ValueError as exc:
        message = str(exc)
        for k, (path, (_, _, label)) in enumerate(zip(args.records, records), 1):
            message = message.replace(f"`v{k}`", f"`v{k}` ({label} of {path})")
        if message == str(exc):
            raise
        raise ValueError(f"{message} Was it recorded with another --design, or are the files "
                         "out of order?") from None
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


def _read_json(path, what):
    from .._io.files import check_readable
    from .._io.readers import read_json_text

    p = check_readable(path, what)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc}).") from None
    return read_json_text(text, p)


def cmd_diagnose(args) -> int:
    from .. import __version__
    from .._diagnose.diagnose import diagnose
    from .._core.model import Hammerstein
    from .._io.modelfile import load_model, model_to_json, pretty_json

    _check_outputs(args, {"--json": args.json, "--plot": args.plot,
                          "--save-model": args.save_model},
                   inputs=[args.model, args.recording], figures={"--plot"})
    model = load_model(args.model)
    if not isinstance(model, Hammerstein):
        raise ValueError(f"{args.model}: diagnose needs the nominal hbjax.Hammerstein model, "
                         f"got {type(model).__name__}.")
    rec = _read_recording(args.recording, args)
    effects = None
    if args.effects is not None:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
        if not effects:  # e.g. an empty shell variable: not a request for every effect
            raise ValueError(f"--effects {args.effects!r} names no effect; give a comma-"
                             "separated list of effect names, or leave --effects out to try "
                             "them all.")
    options = {} if args.criterion is None else {"criterion": args.criterion}
    channels = None if args.no_channels or not rec.channels else dict(rec.channels)
    report = diagnose(model, rec.v, rec.y, holdout=args.holdout, effects=effects,
                      channels=channels, **options)
    offered = f"; channels offered: {', '.join(channels)}" if channels else ""
    print(f"{rec.source}: {len(rec)} samples, nominal model {args.model}{offered}")
    print(report.summary())
    items = []  # written together at the end: all or nothing
    if args.json is not None:
        doc = {"format": "hbjax-diagnosis", "hbjax_version": __version__,
               "model": args.model, "recording": rec.source, "report": report.to_dict()}
        items.append((args.json, pretty_json(doc) + "\n"))
    if args.save_model is not None:
        if report.best is None:
            print(f"no finding: {args.save_model} not written")
        else:
            items.append((args.save_model, model_to_json(report.best.model)))
            print(f"model of the best finding: {type(report.best.model).__name__}")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from .._plot.diagnosis import plot_diagnosis

        fig, axes = plt.subplots(3, 1, figsize=(9, 9), layout="constrained")
        plot_diagnosis(report, axes=axes)
        items.append((args.plot, _figure_bytes(fig, args.plot)))
    _write_all(args, items)
    return 0


def cmd_identify_fit(args) -> int:
    import jax
    import numpy as np

    from .._identify.fit import fit
    from .._io.modelfile import save_model

    _check_outputs(args, {"--out": args.out}, inputs=args.records)  # before the long part
    records = [_read_recording(path, args) for path in args.records]
    options = {} if args.max_steps is None else {"max_steps": args.max_steps}
    if args.loop_tolerance is not None:
        options["loop_tolerance"] = args.loop_tolerance
    result = fit(
        [(r.v, r.y) for r in records], na=args.na, nb=args.nb, m=args.m,
        key=jax.random.key(args.seed), starts=args.starts, criterion=args.criterion,
        initial_state=args.initial_state, **options,
    )
    save_model(args.out, result.model, overwrite=args.force)
    samples = sum(len(r) for r in records)
    print(f"identified (na, nb, m) = ({args.na}, {args.nb}, {args.m}) from {len(records)} "
          f"recording(s), {samples} samples; normalisation B(1) = 1:")
    print(_describe_model(result.model))
    std = np.asarray(result.std)
    print(f"  standard errors (a, b, c1, c2) = {_significant(std, 3)}")
    print(f"  noise std = {float(result.noise_std):.4g}; {args.starts} starts, "
          f"{float(result.hit_rate):.0%} reached the best cost; {result.message}")
    from .._core.display import record_fit_text

    fits = ", ".join(record_fit_text(f) for f in np.atleast_1d(np.asarray(result.sim_fit)))
    start = "estimated initial state" if args.initial_state == "estimate" else "zero start"
    print(f"  free-run fit on the recording(s) ({start}): {fits}")
    print(f"  criterion: {result.criterion_choice or result.criterion}")
    print(f"wrote {args.out}")
    return 0


def cmd_show(args) -> int:
    from .._io.modelfile import load_model

    model = load_model(args.model)
    print(f"{args.model}: {type(model).__name__}")
    print(_describe_model(model))
    return 0
