"""Command-line interface: ``hbjax <command>`` and ``python -m hbjax <command>``.

Every command has ``--help`` with an example. Errors print one line on stderr, prefixed with
the command as typed and naming options as typed (``hbjax identify fit: error: `--m` must
...``), and exit with status 1 (``--debug`` shows the traceback instead); usage errors exit
with status 2; Ctrl-C exits with status 130. Every output path is checked before any work;
outputs are never overwritten unless ``--force`` is given, and are written atomically and
together (all or nothing).
"""

import argparse
import sys
import time

from . import commands as commands
from .commands import SEED_LIMIT
from . import montecarlo as montecarlo

_EPILOG_RECORDINGS = (
    "recording files: CSV with a header row; by default the first column is the input v and "
    "the second the output y; --input NAME / --output NAME select columns by header name "
    "(or 0-based index; a negative index counts from the last column, -1 the last)."
)


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


# ----------------------------------------------------------------------------- option blocks
# Each option that several commands take is defined once here; the help text says what it
# overwrites or seeds for the command at hand.

CRITERIA = ("prediction", "simulation")


def _force(command, help="overwrite --out if it exists"):
    command.add_argument("--force", action="store_true", help=help)


def seed_value(text: str) -> int:
    """A ``--seed``: an integer in [0, 2**63) (a larger one overflowed deep inside JAX with
    an error naming no option)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if not 0 <= value < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"must be in [0, 2**63), got {text}")
    return value


def _seed(command, what="the noise"):
    command.add_argument("--seed", type=seed_value, default=0, help=f"PRNG seed of {what}")


def _design(command):
    command.add_argument("--design", required=True, help="n=ORDER,m=COEFFS,h_m=AMPLITUDE")


def _columns(command):
    """--input / --output: the recording's columns by header name or 0-based index."""
    command.add_argument("--input", default=None, help="input column (default: the first)")
    command.add_argument("--output", default=None, help="output column (default: the second)")


def _criterion(command, default, help, choices=CRITERIA):
    command.add_argument("--criterion", choices=choices, default=default, help=help)



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
    demo.add_argument("--out", default="demo_output", help="folder for the figures")
    _force(demo, "overwrite files in --out")
    demo.add_argument("--samples", dest="n_samples", type=int, default=10_000,
                      help="samples per experiment, at least one period of v3 (default 10000)")
    _seed(demo)
    demo.set_defaults(func=commands.cmd_demo)

    signals = _add_command(
        sub, "signals", parents=[debug],
        help="write the paper's three excitation inputs v1, v2, v3 as CSV files",
        description="Write v1 (eq. 14), v2 (eq. 27) and v3 (eq. 32) for a design to "
        "PREFIX1.csv, PREFIX2.csv, PREFIX3.csv (one column `v`).",
        example="hbjax signals --design n=2,m=3,h_m=4 --samples 2000 --prefix v",
    )
    _design(signals)
    signals.add_argument("--samples", type=int, required=True, help="samples per signal")
    signals.add_argument("--prefix", default="v", help="file name prefix (default: v)")
    _force(signals, "overwrite existing files")
    signals.set_defaults(func=commands.cmd_signals)

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
                          help="input column (header name or index; default: the only column, or the "
                               "v column of a file with columns v and y, else the first)")
    simulate.add_argument("--out", required=True, help="CSV file to write (columns v, y)")
    simulate.add_argument("--noise-std", type=float, default=0.0, help="std of xi(t) (default 0)")
    _seed(simulate)
    simulate.add_argument("--u0", type=float, default=0.0, help="initial backlash output u(-1)")
    _force(simulate)
    simulate.set_defaults(func=commands.cmd_simulate)

    identify = _add_command(
        sub, "identify", parents=[debug],
        help="identify a model from recordings",
        description="Identification methods: `giri` (the paper's closed form on its three "
        "experiments) and `fit` (multi-start fit on any recordings, by default of the free-run "
        "(output-error) criterion).",
        example="hbjax identify giri --design n=2,m=3,h_m=4 y1.csv y2.csv y3.csv --out model.json",
    )
    methods = identify.add_subparsers(dest="method", required=True, metavar="METHOD")
    giri = _add_command(
        methods, "giri", parents=[debug],
        help="the paper's closed-form identification from its three experiments",
        description="Identify the normalised HB-Hammerstein model (paper section 4) from the "
        "outputs y1, y2, y3 of the experiments v1 (eq. 14), v2 (eq. 27), v3 (eq. 32).\n\n"
        "Each record is a CSV file; its output column is --output, by default the second "
        "column (or the only one). A file with two or more columns records its input too: "
        "--input, by default the first column (`v` and `y` by name in the files `hbjax "
        "simulate` writes), which must be the design's signal.",
        example="hbjax identify giri --design n=2,m=3,h_m=4 y1.csv y2.csv y3.csv --out model.json",
    )
    _design(giri)
    giri.add_argument("records", nargs=3, metavar="Yk.csv",
                      help="three CSV files: outputs of v1, v2, v3 (in this order)")
    giri.add_argument("--output", default=None, help="output column (header name or index)")
    giri.add_argument("--input", default=None,
                      help="recorded input column, checked against --design (header name or "
                      "index; default: the first of two or more columns)")
    giri.add_argument("--transient", type=int, default=None,
                      help="samples of y1 to discard (default: settling time of A)")
    giri.add_argument("--out", required=True, help="model file to write (JSON)")
    _force(giri)
    giri.set_defaults(func=commands.cmd_identify_giri)

    mc_keys = "\n".join(f"  {k:<15} {v}" for k, v in montecarlo.MONTE_CARLO_KEYS.items())
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
    _force(mc, "overwrite --out/--plot if they exist")
    mc.set_defaults(func=montecarlo.cmd_montecarlo)

    diag = _add_command(
        sub, "diagnose", parents=[debug],
        help="what does the nominal model leave out of a recording? (hbjax.diagnose)",
        description="Compare a recording of the real system with the nominal model, locate "
        "and name the structured mismatch (saturations, delays, drifts, unmodelled dynamics, "
        "...) and print the readable report; optionally write it as JSON, plot it and save "
        "the extended model of the best finding as a model file. The recording's other "
        "columns (e.g. a recorded force) are offered as channels that may explain the "
        "mismatch (a missing input), as hbjax.diagnose(..., channels=...) takes them; "
        "--no-channels leaves them out.\n\n" + _EPILOG_RECORDINGS,
        example="hbjax diagnose --model model.json rec.csv --json report.json --plot report.png",
    )
    diag.add_argument("--model", required=True, help="nominal model file (a Hammerstein)")
    diag.add_argument("recording", help="CSV recording of the real system")
    _columns(diag)
    diag.add_argument("--holdout", type=float, default=0.3,
                      help="final fraction of the record kept out of every fit (default 0.3)")
    diag.add_argument("--effects", default=None,
                      help="comma-separated effect names to consider (default: all)")
    diag.add_argument("--no-channels", action="store_true",
                      help="do not offer the recording's other columns as channels")
    _criterion(diag, None, "fit criterion: one-step prediction (default) or free-run "
               "simulation error (slow processes)")
    diag.add_argument("--json", default=None, help="write the report as JSON")
    diag.add_argument("--plot", default=None, help="write the report figure (.png, .pdf, .svg)")
    diag.add_argument("--save-model", default=None,
                      help="write the extended model of the best finding (model file)")
    _force(diag, "overwrite output files")
    diag.set_defaults(func=commands.cmd_diagnose)

    fitp = _add_command(
        methods, "fit", parents=[debug],
        help="multi-start fit on ordinary recordings (hbjax.fit)",
        description="Identify an HB-Hammerstein model of orders (na, nb, m) from one or more "
        "recordings with any input (steps, multisines, random levels), by multi-start "
        "Levenberg-Marquardt within the stable models; the model is normalised so that "
        "B(1) = 1. Defaults are for real recordings: the paper's orders (2, 2, 3), the "
        "free-run (output-error) criterion, consistent under measurement noise and the "
        "criterion of a model meant for simulation, and the initial state estimated (real "
        "records rarely start at rest).\n\n"
        + _EPILOG_RECORDINGS,
        example=[
            "hbjax identify fit --na 2 --nb 2 --m 3 rec.csv --out model.json",
            "hbjax identify fit --na 2 --nb 2 --m 3 a.csv b.csv --input drive --output level "
            "--starts 64 --out model.json",
        ],
    )
    fitp.add_argument("records", nargs="+", metavar="REC.csv", help="recordings (input, output)")
    fitp.add_argument("--na", type=int, default=2, help="order of A (default 2)")
    fitp.add_argument("--nb", type=int, default=2, help="order of B (default 2)")
    fitp.add_argument("--m", type=int, default=3,
                      help="coefficients per branch, degree + 1 (default 3)")
    _columns(fitp)
    fitp.add_argument("--starts", type=int, default=32, help="random starts (default 32)")
    _seed(fitp, "the starts")
    _criterion(fitp, "simulation",
               "free-run simulation error (default), one-step prediction error, or auto "
               "(hbjax.fit's default: prediction where its one-step errors are white, else "
               "the free-run refinement of its optimum)", choices=("auto",) + CRITERIA)
    fitp.add_argument("--initial-state", choices=("estimate", "zero"), default="estimate",
                      help="estimate the initial state (default) or start from rest at zero")
    fitp.add_argument("--max-steps", type=int, default=None,
                      help="Levenberg-Marquardt steps per start (default: hbjax.fit's)")
    fitp.add_argument("--loop-tolerance", type=float, default=None,
                      help="largest free-run spread (%%) a loop closing inside the data may "
                           "keep for a success (default: hbjax.fit's, 1; inf accepts any)")
    fitp.add_argument("--out", required=True, help="model file to write (JSON)")
    _force(fitp)
    fitp.set_defaults(func=commands.cmd_identify_fit)

    show = _add_command(
        sub, "show", parents=[debug],
        help="print the parameters of a model file",
        description="Load a model file and print its kind and parameters.",
        example="hbjax show model.json",
    )
    show.add_argument("model", help="model file")
    show.set_defaults(func=commands.cmd_show)
    # Errors are reported as "hbjax identify fit: error: ...", naming options as typed.
    for command in [*sub.choices.values(), *methods.choices.values()]:
        command.set_defaults(
            _prog=command.prog,
            _options={a.dest: max(a.option_strings, key=len) for a in command._actions
                      if a.option_strings and a.dest != "help"},
        )
    return parser


def _as_typed(message: str, options: dict) -> str:
    """A library message with argument names in backticks (`` `m` ``) as the options the
    user typed (`` `--m` ``)."""
    for dest, option in options.items():
        message = message.replace(f"`{dest}`", f"`{option}`")
    return message


def _exit_interrupted(prog: str) -> None:
    """Ctrl-C on the command line: say so and leave at once with status 130.

    A normal interpreter exit would tear down the interpreter while XLA's threads are still
    running the interrupted computation, which can crash (segmentation fault); ``os._exit``
    after flushing the streams does not wait for them."""
    import os
    import signal

    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C cannot cut this short
    except ValueError:  # not the main thread
        pass
    print(f"{prog}: interrupted", file=sys.stderr)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    os._exit(130)


# Seconds a Ctrl-C may take to reach the command as ``KeyboardInterrupt`` before the
# watchdog ends the program itself.
_INTERRUPT_GRACE = 1.0


def _watch_interrupts(prog: str):
    """Record every Ctrl-C, then raise ``KeyboardInterrupt`` as Python's own handler does.

    Python runs the handler between two bytecodes of the main thread, wherever that is; in
    a garbage-collection callback (JAX registers one) the raised ``KeyboardInterrupt`` is
    "ignored" and the command would run on to the end (seen: a Monte Carlo study finished
    and exited 0 after its Ctrl-C). A watchdog thread therefore ends the program with
    status 130 if the main thread has not done so within ``_INTERRUPT_GRACE`` seconds.

    Returns the flag, or ``None`` where handlers cannot be installed (not the main thread)."""
    import signal
    import threading

    flag = threading.Event()

    def on_interrupt(signum, frame):
        flag.set()
        raise KeyboardInterrupt

    def watchdog():
        flag.wait()
        time.sleep(_INTERRUPT_GRACE)
        _exit_interrupted(prog)

    try:
        signal.signal(signal.SIGINT, on_interrupt)
    except ValueError:
        return None
    threading.Thread(target=watchdog, name="hbjax-interrupt", daemon=True).start()
    return flag


def main(argv=None) -> int:
    # The command-line tool is a program of its own: it, not the library, switches on float64.
    import jax

    jax.config.update("jax_enable_x64", True)
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = getattr(args, "_prog", f"hbjax {args.command}")
    interrupted = _watch_interrupts(prog) if argv is None else None
    try:
        status = args.func(args)
        if interrupted is not None and interrupted.is_set():
            # A swallowed Ctrl-C (see _watch_interrupts) and a command that ended before
            # the watchdog: still an interruption, not a success.
            _exit_interrupted(prog)
        return status
    except KeyboardInterrupt:
        if argv is None:  # the program itself (not a call from Python): exit now
            _exit_interrupted(prog)
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one clear line unless --debug
        if interrupted is not None and interrupted.is_set():
            # The Ctrl-C reached Python inside a callback from compiled code, which handed it
            # on as another exception type: it is still an interruption, not an error.
            _exit_interrupted(prog)
        if getattr(args, "debug", False):
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        message = _as_typed(message, getattr(args, "_options", {}))
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
