"""The ``hbjax montecarlo`` command: a study of the paper's experiments from a JSON
config file (:func:`hbjax.monte_carlo`), written as JSON and optionally a figure."""

from .commands import SEED_LIMIT, _check_outputs, _figure_bytes, _parse_design, _read_json, _write_all

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
    if (not isinstance(lengths, list) or not lengths
            or not all(isinstance(n, int) and not isinstance(n, bool) for n in lengths)):
        raise ValueError(f"{path}: `lengths` must be a non-empty list of integers, got {lengths!r}.")
    for key in ("seed", "realisations"):
        value = config.get(key, 0)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{path}: `{key}` must be an integer, got {value!r}.")
    if not 0 <= config.get("seed", 0) < SEED_LIMIT:
        raise ValueError(f"{path}: `seed` must be in [0, 2**63), got {config['seed']}.")
    if not isinstance(config.get("keep_estimates", False), bool):
        raise ValueError(f"{path}: `keep_estimates` must be true or false (a JSON boolean), got "
                         f"{config['keep_estimates']!r}.")
    noise_std = config["noise_std"]
    if isinstance(noise_std, bool) or not isinstance(noise_std, (int, float)):
        raise ValueError(f"{path}: `noise_std` must be a number, got {noise_std!r}.")
    return model, design, config


def cmd_montecarlo(args) -> int:
    import dataclasses

    import jax

    from .. import __version__
    from .._io.modelfile import pretty_json
    from .._misc import jsonable
    from .._montecarlo.run import monte_carlo

    # Every output checked before a long study, not after it.
    _check_outputs(args, {"--out": args.out, "--plot": args.plot},
                   inputs={"the config file": args.config}, figures={"--plot"})
    model, design, config = _study_config(args.config)
    study = monte_carlo(
        model, design,
        noise_std=config["noise_std"], lengths=config["lengths"],
        realisations=config["realisations"], key=jax.random.key(config.get("seed", 0)),
        estimator=config.get("estimator", "giri"), noise=config.get("noise", "equation"),
        chunk_size=config.get("chunk_size"), progress=not args.no_progress,
        keep_estimates=config.get("keep_estimates", False) or args.plot is not None,
    )
    study.table()
    fields = {f.name: jsonable(getattr(study, f.name)) for f in dataclasses.fields(study)}
    if not config.get("keep_estimates", False):
        fields["estimates"] = None
    doc = {"format": "hbjax-study", "hbjax_version": __version__, "config": config,
           "design": {"n": design.n, "m": design.m, "h_m": design.h_m}, "study": fields}
    items = [(args.out, pretty_json(doc) + "\n")]
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        items.append((args.plot, _figure_bytes(study.plot(), args.plot)))
    _write_all(args, items)
    return 0
