"""The ``volcomp`` command line.

Each sub-command lives in ``compensation/commands/<name>.py`` with ``register(subparsers)``.
Errors in user input (``InputError``, ``MachineFileError``, ``ValueError`` subclasses the
library raises on bad data) print one clear line and exit with status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from errormap.io import InputError
from errormap.machine import MachineFileError

# sub-command modules, in the order `volcomp --help` lists them
COMMAND_MODULES = [
    "simulate",
    "featurepoints",
    "predict",
    "train",
    "compensate",
    "report",
    "demo",
    "identify",
    "sweeps",
    "diagnose",
    "calibrate",
    "interpolate",
    "benchmark",
    "drift_predict",
]


class UsageError(ValueError):
    """A command was called with arguments that do not fit together."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="volcomp",
        description="Learned volumetric error compensation for precision machine tools.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(f"compensation.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"compensation.commands.{name}":
                continue  # not built yet
            raise
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (InputError, MachineFileError, UsageError) as exc:
        print(f"volcomp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"volcomp {args.command}: interrupted; nothing half-written", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
