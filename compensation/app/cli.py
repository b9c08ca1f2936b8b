"""The ``volcomp`` command line.

Each sub-command lives in ``compensation/app/commands/<name>.py`` with ``register(subparsers)``.
Only the module of the command being run is imported: ``volcomp --help`` and
``volcomp --version`` list the commands from :data:`COMMAND_HELP` and import no numerical
library (numpy, torch, scipy, MLflow, matplotlib), so they answer in well under a second.
Errors in user input (``InputError``, ``MachineFileError``, ``UsageError``) print one clear
line (at most :data:`MAX_ERROR_CHARS` characters) and exit with status 2.
"""
from __future__ import annotations

import sys

# UsageError and the one-line error format live in validate (stdlib only, imports nothing of ours);
# commands and workflows import them from there, never from this module (it imports every command)
from compensation.app.validate import MAX_ERROR_CHARS, UsageError, caused_by_interrupt, one_line  # noqa: F401

# sub-commands and their one-line help, in the order `volcomp --help` lists them; command
# ``a-b`` lives in ``compensation/app/commands/a_b.py``; tests/test_cli_foundation.py checks that
# each module registers exactly this help
COMMAND_HELP = {
    "simulate": "simulate a truth machine and its measurements (a machine tool: elements, feature points, checks; a serial arm or a hexapod/tripod: measured poses)",
    "featurepoints": "feature points (a grid over the machine's axes) from an element set",
    "predict": "evaluate an error field at axis points (CSV with the machine's axis columns, e.g. x_mm, z_mm, a_deg)",
    "train": "train the error-field network (LM by default) on feature points, tracked in MLflow",
    "compensate": "compensate tool-path files (CSV or G-code) with an error field",
    "report": "compare compensation methods on a path: report.html + metrics.json",
    "demo": "the whole pipeline on the default machine: simulate → train → compensate → report",
    "identify": "identify the machine's error elements from laser-tracker sweeps",
    "sweeps": "simulate laser-tracker axis sweeps of a truth machine tool (sweep CSV)",
    "diagnose": "measured residual -> effects the model lacks, before/after report; or a drift log",
    "calibrate": "identify a parallel machine's (hexapod/tripod) or a serial arm's kinematic parameters from measured poses",
    "register": "re-register a calibrated arm's base frame (and tool point) in a new measurement session from a few poses",
    "interpolate": "hexapod/tripod leg-command program for a tool path",
    "benchmark": "learned vs parametric path on the same machines and measurements: report.html + benchmark.json",
    "drift-predict": "apply a saved drift model to a new log (causal compensation series)",
    "fleet": "identify → train → diagnose every machine of a fleet file, one task per machine (Ray)",
    "machines": "list the built-in machines: name, kind and axes with strokes/limits",
    "export": "write controller compensation tables (ISO 230-1 per-axis, 3D grid, LinuxCNC per-joint, drift coefficients), checked against the model first",
}
COMMAND_MODULES = list(COMMAND_HELP)


def version() -> str:
    """The installed distribution's version, else the package's ``__version__``."""
    try:
        from importlib.metadata import version as _v
        return _v("volcomp")
    except Exception:  # not installed (run from a source tree)
        from errormap import __version__
        return __version__


def command_module(name: str) -> str:
    """The module that holds command ``name`` (``drift-predict`` → ``compensation.app.commands.drift_predict``)."""
    return f"compensation.app.commands.{name.replace('-', '_')}"


def _register(sub, name: str) -> bool:
    import importlib
    try:
        mod = importlib.import_module(command_module(name))
    except ModuleNotFoundError as exc:
        if exc.name == command_module(name):
            return False  # not built yet
        raise
    mod.register(sub)
    return True


def _parser_class():
    """argparse with one-line errors: ``volcomp CMD: error: ... (see volcomp CMD --help)``, exit 2
    (argparse is imported here, inside main's Ctrl-C handling, not when this module loads)."""
    import argparse

    class _Parser(argparse.ArgumentParser):
        def error(self, message):
            print(one_line(f"{self.prog}: error: {message} (see {self.prog} --help)"), file=sys.stderr)
            sys.exit(2)

    return _Parser


def build_parser(commands=None):
    """The argument parser; ``commands``: names whose modules are imported and registered in
    full (default: all); the others get a light entry carrying only their help line."""
    parser = _parser_class()(
        prog="volcomp",
        description="Learned volumetric error compensation for precision machine tools.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    full = set(COMMAND_MODULES if commands is None else commands)
    for name in COMMAND_MODULES:
        if name in full:
            _register(sub, name)
        else:
            sub.add_parser(name, help=COMMAND_HELP[name], add_help=False)
    return parser


def _command_in(argv) -> str | None:
    """The sub-command named in ``argv`` (the first word that is a command), or None."""
    for a in argv:
        if a == "--":
            return None
        if not a.startswith("-"):
            return a if a in COMMAND_HELP else None
    return None


INTERRUPTED_EXIT = 130  # 128 + SIGINT, what a shell reports for a command stopped by Ctrl-C


def main(argv=None) -> int:
    """Run one command; its exit status. Never a traceback for what a user can cause: bad
    arguments, input or output paths (one line, exit 2; :mod:`compensation.app.validate`
    checks every option before any work), Ctrl-C at any moment, also while the numerical
    libraries are still being imported (one line, exit 130; outputs are written through
    temporary files, which an interrupted writer removes, and a command that writes a folder
    runs inside :func:`compensation.app.outputs.owned_folder`, which holds the folder's lock and
    removes on Ctrl-C what the run added, so nothing half-written stays; a command whose --out is one
    file runs inside :func:`compensation.app.outputs.owned_file`, its lock ``FILE.volcomp.lock``)."""
    command, as_program = None, argv is None
    pending = {"interrupt": False}  # set by the SIGINT handler until main() takes the interrupt
    try:
        if as_program:
            _install_interrupt_handler(pending)
        argv = sys.argv[1:] if argv is None else list(argv)
        command = _command_in(argv)
        return _run(argv, command, pending)
    except KeyboardInterrupt:
        return _interrupted(command, as_program, pending)
    except Exception as exc:
        # a Ctrl-C inside a C extension's initialisation comes back as that import's error
        # ("ImportError: initialization failed", the KeyboardInterrupt as its cause)
        # and a Ctrl-C swallowed inside a C callback can leave a library broken (numba: "no compiled
        # object yet"): an error while an interrupt is pending is that interrupt's consequence
        if caused_by_interrupt(exc) or pending["interrupt"]:
            return _interrupted(command, as_program, pending)
        raise


# A Ctrl-C that lands inside a C callback (numba's compiler calls back into Python while it
# compiles a kernel) raises KeyboardInterrupt there, where the callback's caller prints "Exception
# ignored" and goes on: the command would finish as if nothing was pressed. So the handler also
# re-sends the interrupt to the main thread every REARM_S until main() has taken it.
REARM_S = 0.25


def _install_interrupt_handler(pending: dict) -> None:
    """SIGINT → KeyboardInterrupt in the main thread, repeated every :data:`REARM_S` while
    ``pending["interrupt"]`` (until :func:`main` takes it)."""
    import signal
    import threading
    import _thread

    def rearm():
        if pending["interrupt"]:
            _thread.interrupt_main(signal.SIGINT)

    def handler(signum, frame):
        pending["interrupt"] = True
        t = threading.Timer(REARM_S, rearm)
        t.daemon = True
        t.start()
        raise KeyboardInterrupt

    default_hook = sys.unraisablehook

    def unraisable(u):  # the swallowed interrupt is not news: it is being re-sent to main
        if not (isinstance(u.exc_value, KeyboardInterrupt) and pending["interrupt"]):
            default_hook(u)

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # pragma: no cover - not the main thread
        return
    sys.unraisablehook = unraisable


def _interrupted(command, as_program: bool, pending: dict | None = None) -> int:
    import signal
    if pending is not None:
        pending["interrupt"] = False
    if as_program:  # a second Ctrl-C while Python shuts down must not print a traceback either
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # pragma: no cover - not the main thread
            pass
    try:
        print(f"volcomp{' ' + command if command else ''}: interrupted; nothing half-written", file=sys.stderr)
    except (KeyboardInterrupt, OSError):  # pragma: no cover
        pass
    if as_program:
        _exit_now(INTERRUPTED_EXIT)
    return INTERRUPTED_EXIT


def _exit_now(status: int) -> None:
    """End the program with ``status`` without the interpreter's shutdown: an interrupt that landed
    while numba compiled leaves LLVM half-way, and finalising it then can crash the process (signal
    11 after the one-line message, seen in tests/test_cli_robust.py). Everything a command writes is
    already whole or removed (temporary files are cleaned up while the interrupt unwinds); a local
    Ray runtime is shut down first so that no worker outlives the command."""
    import os
    ray = sys.modules.get("ray")
    try:
        if ray is not None and ray.is_initialized():
            ray.shutdown()
    except BaseException:  # pragma: no cover - the exit must happen whatever Ray says
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BaseException:  # pragma: no cover
            pass
    os._exit(status)


def _run(argv, name, pending: dict | None = None) -> int:
    parser = build_parser([name] if name else [])
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from errormap.io import InputError
    from errormap.machine import MachineFileError
    try:
        from compensation.app.validate import check_args
        check_args(args.command, args, _subparser(parser, args.command))
        from compensation.app.outputs import out_targets_of, owned_output
        with owned_output(out_targets_of(args.command, args), args.command,  # one run per --out folder or file;
                          interrupted=lambda: bool(pending and pending["interrupt"])):  # Ctrl-C removes what it added
            return int(args.func(args) or 0)
    except (InputError, MachineFileError, UsageError) as exc:
        print(one_line(f"volcomp {args.command}: error: {exc}"), file=sys.stderr)
        return 2
    except OSError as exc:
        # a file system refusal while writing or reading (permission, disk full, a path that
        # vanished): the user's environment, not a defect of the command
        where = f" {exc.filename}:" if getattr(exc, "filename", None) else ""
        why = exc.strerror or str(exc) or type(exc).__name__
        print(one_line(f"volcomp {args.command}: error:{where} {why}"), file=sys.stderr)
        return 2


def _subparser(parser, name):
    """The sub-parser of command ``name`` (None when the parser has no such command)."""
    import argparse
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return a.choices.get(name)
    return None


if __name__ == "__main__":  # pragma: no cover
    # `python -m compensation.app.cli`: run the imported module's main, so that the UsageError the
    # commands import (compensation.app.cli.UsageError) is the one caught, not __main__'s twin
    from compensation.app.cli import main as _main
    sys.exit(_main())
