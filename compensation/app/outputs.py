"""One run owns an output folder or file: a lock while it works, and nothing left behind by Ctrl-C.

A command that writes a folder (``--out DIR``: the ``OUT_DIR`` rules of :mod:`compensation.app.validate`) runs
inside :func:`owned_folder`, one whose ``--out`` is one file (``OUT_FILE``), and the other one-file outputs,
inside :func:`owned_file`; :func:`owned_output` picks one and is entered in :func:`compensation.app.cli.main`
after the options are checked. The lock (``DIR/.volcomp.lock``, or ``f.csv.volcomp.lock`` beside a file) is
created with ``O_EXCL`` and holds pid, host, command and start time (JSON); a second run is refused (one
line, exit 2), a dead local holder's lock is taken over (said on stderr), another host's never. On
``KeyboardInterrupt`` everything that was not there when the run started is removed (a CSV's provenance
sidecar ``f.meta.json`` too, and ``DIR`` when the run created it). docs/reference/file-formats.md.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path

from errormap.io import OUTPUT_LOCK_NAME as LOCK_NAME  # the lock file's name, shared with the writers

from .validate import UsageError, caused_by_interrupt

CLEANUP_TRIES = 100
"""A Ctrl-C is re-sent every 0.25 s until the command has stopped (cli.REARM_S): the cleanup
starts again from where it was when one lands in it; it removes what is left each time."""


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def file_lock_path(path) -> Path:
    """The lock of the single-file output ``path``: ``f.csv`` -> ``f.csv.volcomp.lock`` beside it."""
    path = Path(path)
    return path.with_name(path.name + LOCK_NAME)


class FolderLock:
    """The lock of one output held by this process (:meth:`acquire`, :meth:`release`): ``DIR/.volcomp.lock``
    of a folder, or ``lock_path`` (:func:`file_lock_path` of a file). ``folder``: the output it guards."""

    def __init__(self, folder, command: str, lock_path=None, flag: str = "--out"):
        self.folder = Path(folder)
        self.flag = flag
        self.path = Path(lock_path) if lock_path is not None else self.folder / LOCK_NAME
        self.command = command
        self.held = False
        self._ino = None

    def _record(self) -> dict:
        return {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}

    def acquire(self) -> "FolderLock":
        """Create the lock or refuse naming its holder; a stale one (dead pid, this host) is taken over."""
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                self._take_over_if_stale()
                continue
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                json.dump(self._record(), fh)
            self._ino = os.stat(self.path).st_ino
            self.held = True
            return self
        raise UsageError(f"{self.flag} {self.folder}: another run took the lock {self.path} while a stale one was removed; "
                         "try again")

    def _take_over_if_stale(self) -> None:
        try:
            holder = json.loads(self.path.read_text(encoding="utf-8"))
            pid, host = int(holder["pid"]), str(holder["host"])
            who = (f"volcomp {holder.get('command', '?')} (pid {pid} on {host}, started "
                   f"{holder.get('started_utc', '?')})")
        except FileNotFoundError:
            return  # released meanwhile: try again
        except (OSError, ValueError, KeyError, TypeError):
            raise UsageError(f"{self.flag} {self.folder}: is locked by {self.path}, which cannot be read (a run may be "
                             "starting); if no volcomp run writes it, remove that file") from None
        if host != socket.gethostname():
            raise UsageError(f"{self.flag} {self.folder}: in use by {who}; wait for it to finish or give another {self.flag} "
                             f"(if that run is gone, remove {self.path})")
        if _pid_alive(pid):
            raise UsageError(f"{self.flag} {self.folder}: in use by {who}; wait for it to finish or give another {self.flag}")
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        print(f"volcomp {self.command}: taking over the stale lock of {who}, which no longer runs, in {self.folder}",
              file=sys.stderr)

    def release(self) -> None:
        """Remove the lock if it is still this run's (a folder replaced whole took it with the old folder)."""
        if not self.held:
            return
        self.held = False
        with contextlib.suppress(OSError):
            if os.stat(self.path).st_ino == self._ino:
                os.unlink(self.path)


def _snapshot(folder: Path) -> set:
    """Every path under ``folder`` (relative strings), links not followed."""
    seen = set()
    for root, dirs, files in os.walk(folder):
        rel = os.path.relpath(root, folder)
        for n in dirs + files:
            seen.add(os.path.normpath(os.path.join(rel, n)))
    return seen


def _remove_new(folder: Path, before: set) -> None:
    """Remove what is under ``folder`` and not in ``before`` (shallowest first: a new folder goes whole)."""
    if not folder.is_dir():
        return
    for rel in sorted(_snapshot(folder) - before, key=lambda r: r.count(os.sep)):
        p = folder / rel
        if rel == LOCK_NAME:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                p.unlink()


def _remove_created(folder: Path, created: Path, whole: bool) -> None:
    """Remove ``folder`` (with what is in it when ``whole``, else only if empty) and the empty
    folders above it up to ``created``, the topmost one this run made. Never a folder above it
    that holds anything: another run may have made it meanwhile."""
    if whole:
        shutil.rmtree(folder, ignore_errors=True)
    p = folder
    while True:
        try:
            p.rmdir()
        except FileNotFoundError:
            pass
        except OSError:  # not empty: someone else's
            return
        if p == created or p.parent == p:
            return
        p = p.parent


def _cleanup(folder: Path, before: set | None, created: Path | None, lock: FolderLock) -> None:
    for _ in range(CLEANUP_TRIES):
        try:
            if created is not None:
                lock.held = False
                _remove_created(folder, created, whole=True)
            else:
                _remove_new(folder, before)
            return
        except KeyboardInterrupt:
            continue


def _is_interrupt(exc: BaseException, interrupted) -> bool:
    """A Ctrl-C (:func:`~compensation.app.validate.caused_by_interrupt`), or any error while ``interrupted()``
    says one is pending (cli.main's handler)."""
    return caused_by_interrupt(exc) or bool(interrupted and interrupted())


def _prepare(path: Path, kind: str, flag: str, folder: Path):
    """Check ``path`` as an output of ``kind`` (one UsageError line) and create ``folder`` with the folders above
    it where absent; returns the topmost folder created (None: it existed)."""
    from errormap.io import InputError, check_output_target
    try:
        check_output_target(path, kind)
    except InputError as exc:
        raise UsageError(f"{flag} {exc}") from None
    created = None
    if not folder.exists():
        created = folder
        while not created.parent.exists():
            created = created.parent
        folder.mkdir(parents=True, exist_ok=True)
    return created


@contextlib.contextmanager
def _owned(path: Path, command: str, kind: str, flag: str, folder: Path, lock_path, interrupted, snapshot, restore):
    """Own the output ``path`` of ``kind`` (``dir``, ``file``) for one run: ``folder`` (itself, or a file's) created
    with the folders above it where absent and removed again if left empty, the lock held while the run works; on
    Ctrl-C ``restore(snapshot(created), created, lock)`` removes what the run added. Yields ``path``."""
    created = _prepare(path, kind, flag, folder)
    lock = FolderLock(path, command, lock_path=lock_path, flag=flag)
    try:
        lock.acquire()
        before = snapshot(created)
    except BaseException:
        if created is not None:
            _remove_created(folder, created, whole=False)  # another run's folder now: only if empty
        raise
    try:
        yield path
    except BaseException as exc:
        if _is_interrupt(exc, interrupted):
            restore(before, created, lock)
        raise
    finally:
        lock.release()
        if created is not None:  # a refused run leaves no folder behind
            _remove_created(folder, created, whole=False)


def owned_folder(folder, command: str, interrupted=None, flag: str = "--out"):
    """Own ``folder`` for one run of ``command``: create it if absent, hold its lock, and on
    Ctrl-C remove what the run added (module docstring). ``interrupted``: a callable that says
    whether a Ctrl-C is pending (an error raised then is its consequence); ``flag``: the option or
    argument that named the folder (in refusals). A context manager yielding the folder's :class:`Path`."""
    folder = Path(folder)
    return _owned(folder, command, "dir", flag, folder, None, interrupted,
                  lambda created: _snapshot(folder) if created is None else None,
                  lambda before, created, lock: _cleanup(folder, before, created, lock))


def owned_file(path, command: str, interrupted=None, flag: str = "--out"):
    """Own the single-file output ``path`` for one run of ``command``: its lock
    (:func:`file_lock_path`, the folder lock's rules) while the run works, the folders above it
    created if absent (and removed again if left empty), and on Ctrl-C the file removed when it was
    not there before the run. A context manager yielding the file's :class:`Path`."""
    from errormap.io import sidecar_path
    path = Path(path)
    files = (path, sidecar_path(path))   # a CSV's provenance sidecar goes with it

    def restore(existed, created, lock):
        for p, was in zip(files, existed):
            if not was:
                with contextlib.suppress(OSError):
                    p.unlink()
    return _owned(path, command, "file", flag, path.parent, file_lock_path(path), interrupted,
                  lambda created: [os.path.lexists(p) for p in files], restore)


COMPENSATE_SUMMARY_NAME = "compensate_summary.json"
"""What ``volcomp compensate`` writes last into its ``--out`` folder: the run's record, which names its outputs."""


def plan_outputs(files, out_dir: Path) -> list:
    """Output path per input; refuses duplicates and outputs that would overwrite an input."""
    from errormap.io import InputError, not_a_file
    inputs = [Path(f) for f in files]
    for p in inputs:
        if not p.is_file():
            raise InputError(not_a_file(p))
    outs = [out_dir / p.name for p in inputs]
    seen = {}
    for p, o in zip(inputs, outs):
        if o.name in seen:
            raise UsageError(f"two inputs would both be written to {o}: {seen[o.name]} and {p}")
        seen[o.name] = p
    resolved_inputs = {p.resolve() for p in inputs}
    for o in outs:
        if o.resolve() in resolved_inputs:
            raise UsageError(f"--out {out_dir} would overwrite the input {o}; choose another folder")
    return list(zip(inputs, outs))


def check_out_dir(out_dir: Path, force: bool) -> list:
    """Refuse a DIR holding files unless ``force``; return the previous run's outputs (to remove)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"--out {out_dir} is not a folder")
    held = sorted(p.name for p in out_dir.iterdir() if not is_lock(p)) if out_dir.is_dir() else []
    if held and not force:
        raise UsageError(f"--out {out_dir} already holds {len(held)} file(s) ({', '.join(held[:3])}"
                         f"{', ...' if len(held) > 3 else ''}); choose an empty folder or pass --force "
                         "(which removes the previous run's outputs)")
    old = []
    summary = out_dir / COMPENSATE_SUMMARY_NAME
    if held and summary.is_file():
        try:
            doc = json.loads(summary.read_text(encoding="utf-8"))
            old = [out_dir / Path(e["output"]).name for e in doc.get("files", []) if e.get("output")]
        except (ValueError, KeyError, TypeError, AttributeError):
            old = []
    return old


def out_targets_of(command: str, args) -> list:
    """``[(path, kind, flag), ...]`` of every output a command's arguments name that is a folder (kind ``"dir"``) or one
    file (``"file"``): its ``--out`` and the other file outputs with an output rule (``identify --report``,
    ``interpolate --report`` / ``--sensitivity-plot``), each path once; [] when it names none. A file prefix
    (``identify --plot``) is not owned: its files are written whole, one by one."""
    from .validate import OutPath, flag_of, rule_for
    out, seen = [], set()
    for dest, value in sorted(vars(args).items()):
        rule = rule_for(command, dest)
        if isinstance(rule, OutPath) and rule.kind in ("dir", "file") and value is not None:
            key = os.path.abspath(str(value))
            if key not in seen:
                seen.add(key)
                out.append((value, rule.kind, flag_of(dest)))
    return out


@contextlib.contextmanager
def owned_output(targets, command: str, interrupted=None):
    """Own every output of ``targets`` (:func:`out_targets_of`; ``(path, kind)`` pairs name ``--out``) for one run: :func:`owned_folder` or
    :func:`owned_file` each, entered in order (a refused one releases those already held)."""
    with contextlib.ExitStack() as stack:
        for path, kind, *flag in targets:   # flag: the option naming it (default --out)
            if kind == "dir":
                stack.enter_context(owned_folder(path, command, interrupted=interrupted))
            else:
                stack.enter_context(owned_file(path, command, interrupted=interrupted, flag=flag[0] if flag else "--out"))
        yield


def is_lock(path) -> bool:
    """Whether ``path`` is a run's lock file (never listed as an output)."""
    return Path(path).name.endswith(LOCK_NAME)
