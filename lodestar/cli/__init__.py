"""The ``lodestar`` command line: one module per subcommand, each with ``add_parser(sub)``
(registers the subcommand and sets ``func``) and ``run(args)`` (returns the exit code).
``lodestar COMMAND --help`` describes each; the README lists them."""

import argparse
import importlib
import sys

COMMANDS = ("detect", "simulate", "goldenset", "db", "demo", "solve", "calibrate", "cosim",
            "regress", "campaign", "synth", "fly")
"""Subcommands, in help order; each is the module ``lodestar.cli.<name>``."""


def build_parser():
    parser = argparse.ArgumentParser(prog="lodestar", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module("lodestar.cli." + name).add_parser(sub)
    return parser


def main(argv=None):
    """Entry point; returns the process exit code (2 on bad input, with a message)."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into e.g. head
        sys.stderr.close()
        return 0
    except (ValueError, OSError, NotImplementedError) as exc:
        print(f"lodestar {args.command}: error: {exc}", file=sys.stderr)
        return 2
