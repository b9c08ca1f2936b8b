"""Every command that writes owns its outputs (compensation/app/outputs.py), checked command by command through
``main``: a second run into an output another live run holds is refused in one line naming the holder, and a
Ctrl-C during the work leaves nothing of what the run added. The commands and their outputs come from the
option rules (compensation/app/validate.py RULES), so a new writing command is covered without a new test."""
from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import socket

import pytest

from compensation.app.cli import build_parser, command_module, main
from compensation.app.outputs import LOCK_NAME, file_lock_path
from compensation.app.validate import MAX_ERROR_CHARS, RULES, OutPath

WRITERS = sorted(c for c, rules in RULES.items()
                 if any(isinstance(r, OutPath) and r.kind in ("dir", "file") for r in rules.values()))
SECONDARY = {"identify": ["--report"], "interpolate": ["--report", "--sensitivity-plot"]}
"""One-file outputs besides ``--out``, owned the same way."""


def _subparser(command):
    parser = build_parser([command])
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return sub.choices[command]


def _argv(command, tmp_path, extra_outs=()) -> tuple[list, list]:
    """A parseable command line of ``command`` (its required options and positionals filled with paths that do not
    exist: nothing is read before the outputs are owned) and ``[(path, kind), ...]`` of the outputs it names."""
    p = _subparser(command)
    argv, outs = [command], []
    required = {id(a) for a in p._actions if a.required}
    for g in p._mutually_exclusive_groups:
        if g.required:
            required.add(id(g._group_actions[0]))
    for a in p._actions:
        if id(a) not in required or a.dest in ("help", "command"):
            continue
        value = a.choices[0] if a.choices else str(tmp_path / f"missing_{a.dest}")
        if a.dest == "out":
            continue
        argv += ([a.option_strings[-1]] if a.option_strings else []) + ([] if a.nargs == 0 else [str(value)])
    for flag in ["--out", *extra_outs]:
        kind = RULES[command][flag[2:].replace("-", "_")].kind
        path = tmp_path / "outs" / (flag[2:] + ("" if kind == "dir" else ".out"))
        argv += [flag, str(path)]
        outs.append((path, kind))
    return argv, outs


def _run(argv):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, err.getvalue()


def _lock_of(path, kind):
    return path / LOCK_NAME if kind == "dir" else file_lock_path(path)


def test_the_writers_are_every_command_with_an_output():
    assert {"simulate", "featurepoints", "predict", "train", "compensate", "report", "demo", "identify", "sweeps",
            "diagnose", "calibrate", "register", "interpolate", "benchmark", "drift-predict", "fleet",
            "export"} <= set(WRITERS)


@pytest.mark.parametrize("command", WRITERS)
def test_a_second_run_into_a_held_output_is_refused_naming_the_holder(command, tmp_path, monkeypatch):
    """Each output in turn is held by a live run (this process, as another volcomp run would): the command is
    refused before its work, in one line naming the holder's command and pid, and the holder's lock stays."""
    argv, outs = _argv(command, tmp_path, SECONDARY.get(command, ()))
    mod = importlib.import_module(command_module(command))
    monkeypatch.setattr(mod, "run", lambda args: pytest.fail(f"{command} ran while its output was held"))
    for path, kind in outs:
        (path if kind == "dir" else path.parent).mkdir(parents=True, exist_ok=True)
        lock = _lock_of(path, kind)
        lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": "holder-run",
                                    "started_utc": "2026-12-02T12:00:00Z"}))
        rc, err = _run(argv)
        lines = err.strip().splitlines()
        assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS, (argv, err)
        flag = next(a for a, b in zip(argv, argv[1:]) if b == str(path))
        assert f"{flag} {path}: in use by volcomp holder-run (pid {os.getpid()}" in lines[0], lines[0]
        assert lock.is_file()
        lock.unlink()


@pytest.mark.parametrize("command", WRITERS)
def test_ctrl_c_during_the_work_leaves_nothing_the_run_added(command, tmp_path, monkeypatch):
    """The command's work writes into each of its outputs, then Ctrl-C lands: exit 130, and neither the outputs nor
    their locks nor the folders the run made are left."""
    argv, outs = _argv(command, tmp_path, SECONDARY.get(command, ()))

    def work(args):
        for path, kind in outs:
            if kind == "dir":
                (path / "sub").mkdir(parents=True)
                (path / "sub" / "half.csv").write_text("x_mm\n1\n")
            else:
                path.write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module(command_module(command)), "run", work)
    rc, err = _run(argv)
    assert rc == 130 and "interrupted; nothing half-written" in err, err
    assert not (tmp_path / "outs").exists(), sorted(str(p) for p in (tmp_path / "outs").rglob("*"))
