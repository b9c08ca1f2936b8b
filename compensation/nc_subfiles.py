"""Subprograms kept outside the program's file (``compensate --subprograms DIR``), found as the controller finds them.

LinuxCNC: ``o<name> call`` of a subroutine the program does not define reads ``DIR/name.ngc`` (the folders in the
order given, as the INI's ``SUBROUTINE_PATH`` is searched; the first that holds the file), which holds
``o<name> sub`` … ``o<name> endsub`` (lines after it, such as ``M2`` or ``%``, are never run).
Fanuc / Haas: ``M98 P9100`` / ``G65 P9100`` of a program the file does not hold finds program O9100 among every
file of every folder by its content, its program-number line ``O9100`` or ``:9100`` (the controller's memory is
one directory of numbers: a file's name says nothing), and a number held by two files is refused naming both.
Every file read is recorded (:attr:`SubprogramFiles.used`: path and SHA-256) for the summary.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

from errormap.io import InputError

from .nc_expand import program_number

MAX_SUBPROGRAM_FILE_BYTES = 64 * 2**20
"""A file larger than this in a folder is not a subprogram (skipped when numbers are looked for)."""
OPTION = "--subprograms"


class SubprogramFiles:
    """The folders ``dirs`` (searched in this order) of subprograms kept outside the program."""

    def __init__(self, dirs):
        self.dirs = tuple(Path(d) for d in dirs)
        for d in self.dirs:
            if not d.is_dir():
                raise InputError(f"{OPTION} {d}: not a folder")
        self._numbers = None
        self.used = {}  # path -> sha256 of every file read

    def named(self) -> str:
        return ", ".join(str(d) for d in self.dirs)

    def read(self, path: Path) -> str:
        data = path.read_bytes()
        self.used[str(path)] = hashlib.sha256(data).hexdigest()
        return data.decode("latin-1")

    def linuxcnc(self, name: str) -> Path | None:
        """The file ``name.ngc`` of the first folder that holds it (``name`` without its ``< >``), or None."""
        for d in self.dirs:
            p = d / f"{name}.ngc"
            if p.is_file():
                return p
        return None

    def fanuc(self, number: int) -> Path | None:
        """The one file whose program-number line is ``O<number>`` / ``:<number>``, or None; two: refused."""
        if self._numbers is None:
            self._numbers = self._index()
        hits = self._numbers.get(number, [])
        if len(hits) > 1:
            raise InputError(f"{OPTION}: program O{number} is in two files, {hits[0]} and {hits[1]} (a controller "
                             "holds one program per number): keep one of them in the folders")
        return hits[0] if hits else None

    def _index(self) -> dict:
        numbers = {}
        for d in self.dirs:
            for p in sorted(d.iterdir()):
                if not p.is_file() or p.stat().st_size > MAX_SUBPROGRAM_FILE_BYTES:
                    continue
                for ln in p.read_bytes().decode("latin-1").splitlines():
                    n = program_number(ln)
                    if n is not None:
                        hits = numbers.setdefault(n, [])
                        if p not in hits:
                            hits.append(p)
        return numbers

    def summary(self) -> list:
        """``[{"path", "sha256"}]`` of the files read, in the order read."""
        return [{"path": p, "sha256": h} for p, h in self.used.items()]
