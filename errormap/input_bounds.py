"""How many rows of each kind of user table a command takes, checked before the table is read.

Every reader names its table's kind (:func:`errormap.io.read_table` ``kind=``); lines are counted in chunks
and, past the kind's :attr:`InputBound.max_rows`, the table is refused unread in one line naming the file, its
rows, the bound and the CPU time and peak memory the command would need (scaled from a measured run,
:attr:`InputBound.ref_rows`, ``ref_cpu_s``, ``ref_bytes``, ``power``). The bounds and the other limits
(documents' bytes, programs, cells, memory): ``docs/reference/file-formats.md``."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class InputBound:
    """The bound of one kind of table. ``what``: its rows in words; ``commands``: who reads it; ``max_rows``: data
    rows taken. The estimate: a measured run of ``ref_rows`` rows took ``ref_cpu_s`` CPU seconds and ``ref_bytes``
    peak resident memory; ``power``: how both grow with the rows (1 linear, 2 a dense n × n or rows × stations
    matrix, 3 dense n × n solves), extrapolated from that run (docs/decisions/020-benchmark-notebook.md "Bounded inputs per command");
    ``power_bytes``: the memory's own growth where it differs from the CPU's (None: ``power``)."""

    what: str
    commands: str
    max_rows: int
    ref_rows: int
    ref_cpu_s: float
    ref_bytes: float
    power: float = 1.0
    power_bytes: float | None = None

    def cost(self, rows: int) -> tuple[float, float]:
        """(CPU s, peak bytes) extrapolated to ``rows``."""
        r = rows / self.ref_rows
        return self.ref_cpu_s * r ** self.power, self.ref_bytes * r ** (self.power_bytes or self.power)

    def estimate(self, rows: int) -> str:
        s, b = self.cost(rows)
        t = f"{s:,.0f} s" if s < 600 else f"{s / 3600:,.2g} h"
        return f"about {t} CPU and {b / 1e9:,.3g} GB"


BOUNDS = {
    "points": InputBound("points", "predict", 5_000_000, 10_000_000, 702.0, 5.6e9),
    "featurepoints": InputBound("feature points", "train", 5_000_000, 10_000_000, 702.0, 5.6e9),
    "checks": InputBound("check measurements", "diagnose", 20_000, 20_000, 70.2, 4.31e9, power=2.0),
    "poses": InputBound("measured poses", "calibrate / register", 20_000, 20_000, 123.6, 1.18e9),
    "sweeps": InputBound("sweep rows", "identify", 5_000, 3_609, 47.7, 2.05e9, power=3.0, power_bytes=2.0),
    "thermal log": InputBound("log samples", "diagnose --drift / drift-predict", 300_000, 110_400, 196.4, 0.823e9),
    "waypoints": InputBound("waypoints", "interpolate", 1_000_000, 10_000_000, 702.0, 5.6e9),
}
"""Kind → bound, each from a measured run of the command reading it (docs/decisions/020-benchmark-notebook.md "Bounded inputs per command"),
chosen so that the command stays within minutes of CPU and a few GB at its bound:

``points``: ``predict`` on 10M rows took 702 s and 5.6 GB; the bound is the largest feature-point set volcomp
writes (``featurepoints --grid`` at validate.MAX_GRID_POINTS), about 2.8 GB. ``featurepoints`` (``train``) and
``waypoints`` (``interpolate``, whose own work is bounded by ``--feed-mm-min`` x ``--period-ms``) are read the same
way and bounded by what volcomp writes (the grid limit; one path's points, validate.MAX_PATH_POINTS).
``checks``: ``diagnose`` holds dense check x check matrices (its learned residual): 20,000 grinder checks took 70 CPU
s and 4.3 GB (1,200: 8.3 s, 0.48 GB), growing as n². ``poses``: ``calibrate`` decides on a subset of 500 poses and
fits the geometric stages on all: 20,000 UR5 poses took 124 CPU s and 1.18 GB (5,000: 78 s, 0.58 GB). ``sweeps``: the one
identification of every machine tool (the grinder through its chain): Gauss-Newton through the block normal
equations (linear in the stations), then the (N, N) covariance (N ≈ 2 × rows, memory as n²) and the smoother's
per-slot station solves (CPU as n³): the grinder's 3,609 rows (401 stations per axis) took 47.7 CPU s and 2.05 GB
(1,809 rows: 10.3 s, 0.67 GB; mill-xyz 3,609 rows: 33.7 s, 1.10 GB); the bound, 5,000 rows, is estimated at about
2 CPU min and 3.9 GB. ``thermal log``:
110,400 samples (460 h at 15 s) took 196 s and 0.82 GB (11,040: 16 s, 0.33 GB).
"""


def refusal(path, kind: str, rows: int) -> str | None:
    """The one-line refusal of the table ``path`` of ``kind`` (a key of :data:`BOUNDS`) with about ``rows`` data
    rows, naming the file, the rows, the bound and the estimate; None within the bound (:func:`errormap.io.read_table`
    raises it as its InputError)."""
    b = BOUNDS[kind]
    if rows <= b.max_rows:
        return None
    return (f"{path}: about {rows:,} rows of {b.what} exceed the limit of {b.max_rows:,} for {b.commands} "
            f"({b.estimate(rows)}); not read: split or subsample it")
