"""Every numeric option and output path of every ``volcomp`` command, checked before any work.

:func:`check_args` runs in :func:`compensation.app.cli.main` between parsing and the command's
``run``: a value out of its range, a size over its limit or an output path of the wrong kind
(a file where a folder belongs, or the reverse) or in a place that cannot be written is one
line and exit status 2 (``UsageError``), before a model is loaded or a file is read.

The rules live in one table, :data:`RULES` (command → option → rule), with :data:`COMMON`
for options that mean the same thing in every command (seeds, workers, chunk sizes);
``tests/test_cli_robust.py`` checks that every ``int``/``float`` option and every output
option of every command has a rule, so a new option cannot slip past.

Sizes derived from the options (the feature-point grid, a flute path's points, the points
per solver chunk, check counts) are bounded by the limits below, each stated in the message
with the largest value that fits.

Only ``math`` and ``os`` are imported at module level (see the note below the imports).
"""
from __future__ import annotations

import math
import os

# nothing else at import time: cli.py imports this module before main() runs, and a Ctrl-C in
# that window (before main's handler) would be a traceback; pathlib, tempfile and the dataclass
# machinery alone took 60-90 ms on the loaded test machine


class UsageError(ValueError):
    """A command was called with arguments that do not fit together (one line, exit status 2);
    ``compensation.app.cli.UsageError`` is this class."""


# an error line longer than this is cut in the middle (a value's repr can be megabytes)
MAX_ERROR_CHARS = 300


def caused_by_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is a Ctrl-C: a KeyboardInterrupt, or an error it caused (its cause or context)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def one_line(msg: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``msg`` on one line, cut in the middle to at most ``limit`` characters."""
    s = " ".join(str(msg).split())
    if len(s) <= limit:
        return s
    keep = limit - 5
    return s[: keep - keep // 3] + " ... " + s[len(s) - keep // 3:]


# --- size limits (stated in the messages) ----------------------------------------------------
# feature-point grid: n³ points; at the limit (--grid 170, 4.9e6 points) featurepoints peaks at
# 0.65 GB and takes 46 s CPU, a 420 MB CSV (measured); 1000³ was killed at ~24 GB
MAX_GRID_POINTS = 5_000_000
# points of one generated tool path (flute turns × points per turn): the flute is integrated on
# 16 sub-steps per point and every method solves every point; 1e6 points is 360× the default
MAX_PATH_POINTS = 1_000_000
# points per solver chunk (the unit of work and memory one worker holds): 16× the default 65,536
MAX_CHUNK_POINTS = 1_048_576
# simulated check measurements / random check points of an export: one row each, in memory at once
MAX_CHECKS = 1_000_000
# bootstrap draws (each a full identification): beyond this the covariance no longer changes
MAX_BOOTSTRAP = 100_000
# per-point GA runs of a report (each a whole GA): beyond the path's own point limit there is nothing to run
MAX_GA_POINTS = MAX_PATH_POINTS
# threads or Ray CPUs on this machine
MAX_WORKERS = 4096
# seeds: numpy, torch and PyGAD all take a seed in [0, 2**32)
MAX_SEED = 2**32 - 1
# network size: parameters of the BP network (the paper's 10,15,25,15,10 has 1,188); the LM
# Hessian alone is P² float64 (20,000 parameters: 3.2 GB)
MAX_NETWORK_PARAMS = 20_000
# LM holds the whole Jacobian (3 × feature points × parameters) and the Hessian in float64
MAX_LM_BYTES = 4 * 2**30
# points evaluated by one predict call (memory of a batch; a network holds every layer's
# activations of the batch)
PREDICT_BATCH = 65_536
# interpolate: the contour step f = feed × period; below 1 μm a metre of path is over 1e6 steps
MIN_CONTOUR_STEP_MM = 1e-3
# iteration counts (LM iterations: each a Jacobian over the whole feature-point set)
MAX_ITER = 10_000_000


# --- rules --------------------------------------------------------------------------------------
class Count:
    """An integer in ``[lo, hi]`` (``hi`` None: no upper limit); ``what`` names the limit's reason."""

    def __init__(self, lo: int = 1, hi: int | None = None, what: str = ""):
        self.lo, self.hi, self.what = lo, hi, what

    def check(self, flag: str, v) -> None:
        if not isinstance(v, int) or isinstance(v, bool):
            raise UsageError(f"{flag}: expected an integer, got {v!r}")
        if v < self.lo:
            raise UsageError(f"{flag} must be >= {self.lo}, got {v}")
        if self.hi is not None and v > self.hi:
            why = f" ({self.what})" if self.what else ""
            raise UsageError(f"{flag}: {v} exceeds the limit of {self.hi:,}{why}")


class Each:
    """A repeatable option (a list): every value by ``rule``."""

    def __init__(self, rule):
        self.rule = rule

    def check(self, flag: str, v) -> None:
        for x in (v if isinstance(v, (list, tuple)) else [v]):
            self.rule.check(flag, x)


# benchmark --checks: a check file's own minimum (errormap/diagnosis/chain_checks.py refuses fewer than 10); the
# learned stage declines below 84 (its 50 fitting checks at the 60/40 split): those rows say so
MIN_BENCHMARK_CHECKS = 10


class Number:
    """A finite float with optional bounds; ``open_lo``/``open_hi``: the bound itself is excluded."""

    def __init__(self, lo: float | None = None, hi: float | None = None, open_lo: bool = False,
                 open_hi: bool = False, unit: str = ""):
        self.lo, self.hi, self.open_lo, self.open_hi, self.unit = lo, hi, open_lo, open_hi, unit

    def check(self, flag: str, v) -> None:
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise UsageError(f"{flag}: expected a number, got {v!r}") from None
        ok = math.isfinite(x)
        if ok and self.lo is not None:
            ok = x > self.lo if self.open_lo else x >= self.lo
        if ok and self.hi is not None:
            ok = x < self.hi if self.open_hi else x <= self.hi
        if not ok:
            raise UsageError(f"{flag}: expected {self.describe()}, got {v}")

    def describe(self) -> str:
        u = f" {self.unit}" if self.unit else ""
        if self.lo is not None and self.hi is not None:
            return (f"a number in {'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}"
                    f"{')' if self.open_hi else ']'}{u}")
        if self.lo is not None:
            return f"a finite number {'>' if self.open_lo else '>='} {self.lo:g}{u}"
        if self.hi is not None:
            return f"a finite number {'<' if self.open_hi else '<='} {self.hi:g}{u}"
        return f"a finite number{u}"


class Ranged:
    """A :class:`Number` whose bounds are a library constant ``module.NAME`` (a ``(lo, hi)`` pair,
    resolved when checked: nothing is imported before main's Ctrl-C handling)."""

    def __init__(self, module: str, name: str, unit: str = ""):
        self.module, self.name, self.unit = module, name, unit

    def number(self) -> Number:
        import importlib
        lo, hi = getattr(importlib.import_module(self.module), self.name)
        return Number(lo, hi, unit=self.unit)

    def check(self, flag: str, v) -> None:
        self.number().check(flag, v)


class SegmentLength(Ranged):
    """``compensate --max-segment-mm``: ``auto``, ``none`` or a length in the range."""

    def check(self, flag: str, v) -> None:
        if str(v).strip().lower() in ("auto", "none"):
            return
        rule = self.number()
        try:
            rule.check(flag, v)
        except UsageError:
            raise UsageError(f"{flag}: expected 'auto', 'none' or {rule.describe()}, got {v!r}") from None


class OutPath:
    """An output path: ``kind`` ``"dir"`` (a folder the command creates or fills), ``"file"``
    (a file it writes whole) or ``"prefix"`` (files named PREFIX_*: the prefix's folder)."""

    def __init__(self, kind: str):
        self.kind = kind

    def check(self, flag: str, v) -> None:
        check_output_path(flag, v, self.kind)


def positive(unit: str = "") -> Number:
    return Number(lo=0.0, open_lo=True, unit=unit)


def non_negative(unit: str = "") -> Number:
    return Number(lo=0.0, unit=unit)


FRACTION = Number(lo=0.0, hi=1.0, open_lo=True, open_hi=True)
FINITE = Number()
SEED = Count(0, MAX_SEED, "seeds are 32-bit")
ITER = Count(1, MAX_ITER, "iterations")
OUT_DIR, OUT_FILE, OUT_PREFIX = OutPath("dir"), OutPath("file"), OutPath("prefix")

# options that mean the same in every command that has them
COMMON = {
    "seed": SEED, "sim_seed": SEED, "truth_seed": SEED, "seed_noise": SEED, "seed_check_noise": SEED,
    "workers": Count(1, MAX_WORKERS, "workers"),
    "chunk_points": Count(1, MAX_CHUNK_POINTS, "points per chunk held in memory by one worker"),
}

# the flute path's settings (report, demo); its size is checked as a whole in _check_flute
FLUTE = {"turns": positive(), "points_per_turn": Count(2, MAX_PATH_POINTS, "points of one path"),
         "radius_mm": positive("mm"), "helix_start_deg": Number(0.0, 90.0, True, True, "deg"),
         "helix_end_deg": Number(0.0, 90.0, True, True, "deg"), "px_start_mm": FINITE}
METHODS = {"ga_points": Count(1, MAX_GA_POINTS, "per-point GA runs"), "ga_budget_s": positive("s")}


class Trainer:
    """``demo --trainer``: one of ``training.trainers.TRAINERS`` (checked here, not after the simulation)."""

    def check(self, flag: str, v) -> None:
        from training.trainers import TRAINERS
        if v not in TRAINERS:
            raise UsageError(f"{flag}: expected one of {', '.join(TRAINERS)}, got {v!r}")


class Grid:
    """Points per axis of an n×n×n grid: n >= 2 and n³ <= :data:`MAX_GRID_POINTS`."""

    def check(self, flag: str, v) -> None:
        Count(2).check(flag, v)
        if v ** 3 > MAX_GRID_POINTS:
            n_max = round(MAX_GRID_POINTS ** (1 / 3))
            n_max -= n_max ** 3 > MAX_GRID_POINTS
            raise UsageError(f"{flag}: grid {v}³ = {float(v) ** 3:.3g} points exceeds the limit of "
                             f"{MAX_GRID_POINTS:.0e} ({flag} <= {n_max})")


GRID = Grid()


def network_params(hidden, a_encoding: str = "raw") -> int:
    """Weights and biases of the BP network with ``hidden`` widths (3 or 4 inputs, 3 outputs)."""
    sizes = [4 if a_encoding == "periodic" else 3, *hidden, 3]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


class Widths:
    """``--hidden``: comma-separated layer widths >= 1, at most :data:`MAX_NETWORK_PARAMS` parameters."""

    def check(self, flag: str, v) -> None:
        try:
            hidden = [int(h) for h in str(v).split(",")]
        except ValueError:
            raise UsageError(f"{flag}: expected comma-separated integers, got {v!r}") from None
        if not hidden or min(hidden) < 1:
            raise UsageError(f"{flag}: expected widths >= 1, got {v!r}")
        n = network_params(hidden, "periodic")
        if n > MAX_NETWORK_PARAMS:
            raise UsageError(f"{flag}: a network {v} has {n:,} parameters, over the limit of "
                             f"{MAX_NETWORK_PARAMS:,} (the paper's 10,15,25,15,10 has {network_params((10, 15, 25, 15, 10)):,})")


def check_lm_size(n_points: int, p: int) -> None:
    """Refuse an LM fit of ``p`` network parameters whose Jacobian (3n × P) and Hessian (P × P),
    float64, exceed :data:`MAX_LM_BYTES`."""
    need = 8 * (3 * n_points * p + p * p)
    if need > MAX_LM_BYTES:
        n_max = max(0, (MAX_LM_BYTES // 8 - p * p) // (3 * p))
        raise UsageError(f"--trainer lm: {n_points:,} feature points x {p:,} network parameters need "
                         f"{need / 2**30:.3g} GiB for the Jacobian, over the limit of {MAX_LM_BYTES / 2**30:g} GiB "
                         f"(at most {n_max:,} points for this network; or --trainer adam / lbfgs)")


def predict_batched(field, axes, conditions=None):
    """``field.predict(axes)`` in batches of :data:`PREDICT_BATCH` points: bounded memory. Shape (n, 3).
    ``conditions``: per-point conditions ``{name: (n,)}`` of the field's terms, travelling with their points."""
    import numpy as np

    def batch(i):
        j = i + PREDICT_BATCH
        f = field if conditions is None else field.with_conditions({c: v[i:j] for c, v in conditions.items()})
        return f.predict(axes[i:j])
    if len(axes) <= PREDICT_BATCH:
        return batch(0)
    return np.concatenate([batch(i) for i in range(0, len(axes), PREDICT_BATCH)])

RULES: dict[str, dict] = {
    "simulate": {"noise_um": non_negative("um"), "checks": Count(1, MAX_CHECKS, "check measurements"),
                 "poses": Count(3, MAX_CHECKS, "poses"), "out": OUT_DIR},
    "featurepoints": {"grid": GRID, "out": OUT_FILE},
    "predict": {"out": OUT_FILE},
    "train": {"out": OUT_DIR, "hidden": Widths(), "max_time": positive("s"), "mse_goal": non_negative(), "max_iter": ITER,
              "threads": Count(1, MAX_WORKERS, "threads"),
              "physics_stations": Count(4, 61, "stations per axis of the fitted element set")},
    "compensate": {"out": OUT_DIR, "show": Count(1), "arc_tolerance_um": Ranged("compensation.pathio", "ARC_TOLERANCE_RANGE_UM", "um"),
                   "max_segment_mm": SegmentLength("compensation.pathio", "SEGMENT_RANGE_MM", "mm"), "temp_c": FINITE,
                   "time_s": FINITE, "max_rotary_correction_deg": Number(0.0, 180.0, open_lo=True, unit="deg")},
    "report": {"out": OUT_DIR, **METHODS, **FLUTE},
    "demo": {"out": OUT_DIR, "hidden": Widths(), "trainer": Trainer(), "train_iter": ITER, "train_s": positive("s"),
             "train_patience": Count(0, MAX_ITER, "LM iterations without improvement (0: off)"), **METHODS, **FLUTE},
    "identify": {"out": OUT_FILE, "report": OUT_FILE, "plot": OUT_PREFIX, "noise_um": positive("um"),
                 "bootstrap": Count(2, MAX_BOOTSTRAP, "bootstrap draws")},
    "sweeps": {"out": OUT_FILE, "noise_um": non_negative("um"), "warmup_c": Number(-100.0, 100.0, unit="degC")},
    "diagnose": {"out": OUT_DIR, "fit_fraction": FRACTION, "alpha": FRACTION, "max_effects": Count(1),
                 "noise_um": positive("um"), "retrain_iter": ITER, "retrain_time_s": positive("s")},
    "calibrate": {"out": OUT_DIR, "holdout": FRACTION, "noise_um": positive("um"), "lever_mm": positive("mm"),
                  "folds": Count(2, 20, "CV folds of the learned stage")},
    "register": {"out": OUT_DIR, "fit_poses": Count(6, None, "poses a registration takes")},
    "interpolate": {"out": OUT_FILE, "report": OUT_FILE, "sensitivity_plot": OUT_FILE,
                    "feed_mm_min": positive("mm/min"), "period_ms": positive("ms")},
    "benchmark": {"out": OUT_DIR, "train_iter": ITER, "train_s": positive("s"),
                  "checks": Each(Count(MIN_BENCHMARK_CHECKS, MAX_CHECKS, "check measurements"))},
    "drift-predict": {"out": OUT_FILE, "noise_um": positive("um"), "drift_per_h": non_negative("um/h")},
    "fleet": {"out": OUT_DIR, "hidden": Widths(), "train_iter": ITER, "grid": GRID, "bootstrap": Count(2, MAX_BOOTSTRAP, "bootstrap draws")},
    "export": {"out": OUT_DIR, "tolerance_um": positive("um"), "points": Count(2),
               "check_points": Count(1, MAX_CHECKS, "check points"), "sample_period_s": positive("s")},
}


def rule_for(command: str, dest: str):
    """The rule of option ``dest`` of ``command`` (None: the option has none)."""
    return RULES.get(command, {}).get(dest) or COMMON.get(dest)


def flag_of(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def check_args(command: str, args, parser=None) -> None:
    """Check every option of ``args`` (a parsed namespace of ``command``) that has a rule.

    ``parser``: the command's sub-parser, to name the option as the user typed it (a
    positional's metavar); options left at None (not given, no default) are not checked.
    Raises :class:`UsageError` (one line) on the first bad value.
    """
    flags = _flags(parser)
    outs = []
    for dest, value in sorted(vars(args).items()):
        rule = rule_for(command, dest)
        if rule is None or value is None:
            continue
        flag = flags.get(dest, flag_of(dest))
        if isinstance(rule, OutPath):
            outs.append((flag, value, rule))   # paths after the numbers: cheap checks first
            continue
        rule.check(flag, value)
    # (fleet opens its store itself, after refusing a file store that several machines would write at once:
    # opening a SQLite URI creates its file)
    if getattr(args, "tracking_uri", None) and not getattr(args, "no_track", False) and command != "fleet":
        from training.tracking import check_tracking_uri   # a store MLflow cannot open: refused before the work
        check_tracking_uri(args.tracking_uri)
    if command in ("report", "demo"):
        _check_flute(args)
    if command == "interpolate":
        step_mm = args.feed_mm_min / 60.0 * args.period_ms / 1000.0
        if step_mm < MIN_CONTOUR_STEP_MM:
            raise UsageError(f"--feed-mm-min {args.feed_mm_min:g} x --period-ms {args.period_ms:g}: contour step "
                             f"{step_mm:.3g} mm is under the limit of {MIN_CONTOUR_STEP_MM:g} mm (over 1e6 steps per "
                             "metre of path)")
    for flag, value, rule in outs:
        rule.check(flag, value)
    _refuse_output_onto_input(command, args, outs, flags)


def _refuse_output_onto_input(command: str, args, outs, flags) -> None:
    """A file output that IS one of the command's input files (the same file by any path: a link, ``./``) would
    replace that input with the result: refused naming both (``--out p.csv`` beside the input ``p.csv``)."""
    import os
    files = [(flag, v) for flag, v, rule in outs if rule.kind == "file"]
    if not files:
        return
    out_dests = {dest for dest in vars(args) if isinstance(rule_for(command, dest), OutPath)}
    for dest, value in sorted(vars(args).items()):
        if dest in out_dests or dest in ("func", "command"):
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if not isinstance(v, (str, os.PathLike)) or not os.path.isfile(v):
                continue
            for flag, out in files:
                try:
                    same = os.path.exists(out) and os.path.samefile(v, out)
                except OSError:
                    same = False
                if same:
                    raise UsageError(f"{flag} {out}: is the input {flags.get(dest, flag_of(dest))} {v}; writing there "
                                     "would replace the input with the result: choose another output file")


def _flags(parser) -> dict:
    if parser is None:
        return {}
    out = {}
    for a in parser._actions:
        if a.option_strings:
            out[a.dest] = max(a.option_strings, key=len)
        else:
            out[a.dest] = str(a.metavar or a.dest).upper()
    return out


def _check_flute(args) -> None:
    """The flute path's point count ``round(turns × points per turn)`` against :data:`MAX_PATH_POINTS`."""
    if getattr(args, "flute", True) is False:  # report --path FILE: no flute
        return
    n = args.turns * args.points_per_turn
    if n > MAX_PATH_POINTS + 0.5:
        raise UsageError(f"flute path: --turns {args.turns:g} x --points-per-turn {args.points_per_turn} = "
                         f"{n:.4g} points exceeds the limit of {MAX_PATH_POINTS:.0e} points per path "
                         f"(--turns <= {MAX_PATH_POINTS / args.points_per_turn:.4g} at this --points-per-turn)")
    if round(n) < 2:
        raise UsageError(f"flute path: --turns {args.turns:g} x --points-per-turn {args.points_per_turn} gives "
                         f"{round(n)} point(s); a path needs at least 2")


# --- output paths -------------------------------------------------------------------------------
def check_output_path(flag: str, value, kind: str) -> None:
    """``value`` can be written as a ``kind`` (``dir``, ``file`` or ``prefix``): nothing of the
    wrong kind is in the way, no component of its folder is a file, and the nearest existing
    folder accepts a new file (probed by creating and removing one: permissions, read-only
    mounts and ownership all answer the same way, also for root)."""
    from pathlib import Path
    text = str(value)
    if not text.strip():
        raise UsageError(f"{flag}: expected a path, got an empty string")
    if "\0" in text:
        raise UsageError(f"{flag}: a path cannot contain a NUL character")
    p = Path(text)
    _check_not_special(flag, p)
    if kind == "dir":
        if p.exists() and not p.is_dir():
            raise UsageError(f"{flag} {text}: is a file; expected a folder (the command writes several files into it)")
        start = p
    else:
        if text.endswith(("/", os.sep)) or p.is_dir():
            what = "file prefix" if kind == "prefix" else "file"
            raise UsageError(f"{flag} {text}: is a folder; expected a {what} name")
        start = p.parent
    folder = _nearest_existing(start)
    if folder is None or not folder.is_dir():
        raise UsageError(f"{flag} {text}: {folder} is a file, not a folder; it cannot hold the output")
    _probe_writable(flag, text, folder)


def _check_not_special(flag: str, p) -> None:
    """Refuse an output path that is a device, FIFO or socket (or a link to one): see
    :func:`errormap.io.check_output_target`, which every writer runs again."""
    from errormap.io import InputError, check_output_target
    try:
        check_output_target(p, "any")
    except InputError as exc:
        raise UsageError(f"{flag} {exc}") from None


def _nearest_existing(p):
    from pathlib import Path
    p = Path(os.path.abspath(p))
    while True:
        if p.exists():
            return p
        if p.is_symlink():  # a dangling link: nothing can be written through it
            return p
        if p.parent == p:
            return None
        p = p.parent


def _probe_writable(flag: str, text: str, folder) -> None:
    import tempfile
    try:
        fd, probe = tempfile.mkstemp(prefix=".volcomp-write-probe.", dir=folder)
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise UsageError(f"{flag} {text}: cannot write in {folder} ({why})") from None
    os.close(fd)
    try:
        os.unlink(probe)
    except OSError:  # pragma: no cover - a file we just made
        pass


def allowed_verdict(verdict) -> str | None:
    """``failed-verdict (FILE: verdict failed: REASONS)``: what an output records of a failed diagnosis
    verdict used with ``--allow failed-verdict`` (``verdict``: :func:`compensation.fields.check_verdict`'s
    record); None when none was overridden."""
    if not verdict or not verdict.get("overridden_by"):
        return None
    from compensation.fields import FAILED_VERDICT
    reasons = "; ".join(verdict["reasons"]) or "no reasons recorded"
    return f"{FAILED_VERDICT} ({verdict['file']}: verdict failed: {reasons})"


EXIT_FAILED_VERDICT = 1
"""A diagnosis that ran but whose verdict failed (its model loses to a plain baseline, or the noise it estimates
is far above the stated one): the files are written, with the verdict in them, and the status is 1 (as
``calibrate``'s ``success: false``)."""
