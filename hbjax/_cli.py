"""Command-line interface: ``hbjax <command>`` and ``python -m hbjax <command>``."""

import argparse
import sys


def _cmd_demo(args) -> int:
    from ._demo import run_demo

    run_demo(args.out, force=args.force, n_samples=args.samples, seed=args.seed)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hbjax",
        description="Identify Hammerstein systems with hysteresis-backlash input nonlinearity.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on error")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser(
        "demo",
        help="simulate the default system, run the paper's three experiments, identify it",
        description="The main job on the embedded default system.",
        epilog="example: hbjax demo --out demo_output",
    )
    demo.add_argument("--out", default="demo_output", help="folder for the figures and table")
    demo.add_argument("--force", action="store_true", help="overwrite files in --out")
    demo.add_argument("--samples", type=int, default=10_000, help="samples per experiment")
    demo.add_argument("--seed", type=int, default=0, help="PRNG seed of the noise")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except Exception as exc:  # one clear line unless --debug
        if args.debug:
            raise
        print(f"hbjax {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
