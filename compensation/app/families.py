"""The machine-family registry: the one place in the application that knows machine kinds.

A loaded machine's family (:func:`family_of`) answers what the commands used to ask by comparing
``machine.kind`` with strings: which workflow runs a command for it (:meth:`Family.target`), the
facts a command branches on (:class:`Facts`: tracker sweeps, G-code words, measured poses, the
element chain, a platform orientation ...) and which options it refuses, with the reason, in the
words of ``docs/reference/features.md`` (:meth:`Family.refuse_unsupported`). ``tests/test_family_registry.py``
checks the declared gaps against that table's cells.

Three families, the columns of that table: **machine tool** (every chain file, the built-in grinder among them,
and a ``kind = "grinder"`` file read as its chain), **serial arm** and **parallel** (hexapod, tripod). Where a
command differs between machines of one family, the difference is a fact of the loaded machine
(:attr:`Family.machine_facts`: e.g. whether the flute path runs on it), never its kind string. A new kind
is one entry of :data:`FAMILIES` (and its parser in :func:`errormap.machine.machine_kinds`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..batch import CHUNK_POINTS
from ..gcode_words import DEFAULT_RAPIDS
from ..pathio import DEFAULT_ARC_TOLERANCE_UM
from ..toolpath import FLUTE_DEFAULTS, runs_flute
from .validate import UsageError

YES, PHYSICS, OTHER_PATH, NOT_YET = "yes", "physics", "other path", "not yet"
GAP_WORDS = (PHYSICS, OTHER_PATH, NOT_YET)
"""A gap's first word, as the cells of docs/reference/features.md spell it (there followed by a colon)."""


@dataclass(frozen=True)
class Facts:
    """What a machine kind is, as far as a command asks: ``tracker_sweeps`` (identified from per-axis
    laser-tracker sweeps and feature points over its axis columns), ``gcode`` (its programs are G-code in
    its axis words; every machine tool is its element chain, :mod:`errormap.machine_tool`),
    ``poses`` (calibrated from measured poses), ``platform_orientation`` (a pose has a platform
    orientation, ``rx_deg, ry_deg, rz_deg``: a hexapod), ``sensitivity_study`` (the tripod's
    error-sensitivity study, ``interpolate --sensitivity-plot``), ``paper_paths`` (the hexapod paper's test
    passes, sphere and hyperboloid, are its benchmark paths and noise/pose series). Of the loaded machine tool
    (:func:`machine_tool_facts`): ``flute_axes`` (the flute path runs on it, :func:`compensation.toolpath.runs_flute`:
    the workpiece turned about X by a full-turn A, X and one radial linear axis), ``fixed_tool_axis`` (three axes,
    one rotary: all of them place the tool point and none is left to turn the tool axis)."""

    tracker_sweeps: bool = False
    gcode: bool = False
    poses: bool = False
    platform_orientation: bool = False
    sensitivity_study: bool = False
    paper_paths: bool = False
    flute_axes: bool = False
    fixed_tool_axis: bool = False


@dataclass(frozen=True)
class Opt:
    """One option of a refusal: its ``flag``, the ``word`` of its gap in docs/reference/features.md, the value that means
    "not given" besides None / False / empty (``default``), whether the message shows the value
    (``show_value``) and the attribute of the parsed arguments (``dest``, from the flag by default)."""

    flag: str
    word: str
    default: object = None
    show_value: bool = False
    dest: str = ""

    def given(self, args):
        """The option as the message names it (``--flag`` or ``--flag VALUE``), or None when not given."""
        v = getattr(args, self.dest or self.flag.lstrip("-").replace("-", "_"), None)
        if v is None or v is False or (isinstance(v, (list, tuple)) and not v) or v == self.default:
            return None
        return f"{self.flag} {v}" if self.show_value else self.flag


@dataclass(frozen=True)
class Refusal:
    """Options of ``command`` a family refuses (exit status 2, one line, nothing written). ``message`` is
    formatted with ``given`` (the given options, comma-separated), ``does``/``it`` (singular or plural),
    ``kind``, ``name`` and ``path`` of the machine; ``kinds``: only these kinds of the family refuse them;
    ``when`` / ``unless``: only a machine with / without that fact (:class:`Facts`) refuses them."""

    command: str
    options: tuple
    message: str
    kinds: tuple = ()
    when: str = ""
    unless: str = ""

    def applies(self, kind: str, facts: Facts) -> bool:
        return ((not self.kinds or kind in self.kinds) and (not self.when or getattr(facts, self.when))
                and not (self.unless and getattr(facts, self.unless)))


@dataclass(frozen=True)
class Gap:
    """A command a family does not run: the gap's ``word`` and ``reason`` (its docs/reference/features.md cell);
    ``unless``: a fact (:class:`Facts`) of the machines of the family that do run it (the command is a target too)."""

    word: str
    reason: str
    unless: str = ""


@dataclass(frozen=True)
class Family:
    """One family (a column of docs/reference/features.md): ``name`` of the family, ``column`` of the table,
    ``kinds`` ``{kind: Facts}``, ``targets`` ``{command: target}`` (the workflow that runs the command for it;
    a command looks its runner up by this name), ``gaps`` ``{command: Gap}`` (commands it does not run, or runs only on machines with
    the gap's ``unless`` fact), ``refusals`` (options it refuses), ``machine_facts`` (``machine -> {fact: value}``,
    the facts of :class:`Facts` read from a loaded machine). :func:`family_of` binds it to one machine (``kind``,
    ``path``, ``machine_name`` and its ``bound_facts``)."""

    name: str
    column: str
    kinds: dict
    targets: dict
    gaps: dict = field(default_factory=dict)
    refusals: tuple = ()
    machine_facts: object = None
    kind: str = ""
    path: str = ""
    machine_name: str = ""
    bound_facts: Facts | None = None

    @property
    def facts(self) -> Facts:
        """The facts of the bound machine (those of its kind where no machine is bound)."""
        return self.kinds[self.kind] if self.bound_facts is None else self.bound_facts

    def _gap(self, command: str) -> Gap | None:
        g = self.gaps.get(command)
        if command in self.targets and (g is None or (g.unless and getattr(self.facts, g.unless))):
            return None
        return g

    def runs(self, command: str) -> bool:
        return self._gap(command) is None and command in self.targets

    def target(self, command: str) -> str:
        """The workflow that runs ``command`` for this family; :class:`UsageError` naming the gap (and the
        way this family does the job, where there is one) when it does not run it."""
        g = self._gap(command)
        if g is not None:
            raise UsageError(f"{self.path}: volcomp {command} does not run on a {self.name} "
                             f"({self.kind} {self.machine_name!r}): {g.word}: {g.reason}")
        return self.targets[command]

    def refuse_unsupported(self, command: str, args) -> None:
        """Raise :class:`UsageError` for the first refusal of ``command`` whose options ``args`` gives (never an
        option silently ignored); the message is the registry's, with the given options named."""
        for r in (r for r in self.refusals if r.command == command and r.applies(self.kind, self.facts)):
            given = [g for g in (o.given(args) for o in r.options) if g]
            if given:
                one = len(given) == 1
                raise UsageError(r.message.format(given=", ".join(given), does="does" if one else "do",
                                                  it="it" if one else "them", kind=self.kind,
                                                  name=self.machine_name, path=self.path))

    def support(self, command: str, option: str) -> tuple:
        """``(word, reason)`` of ``option`` of ``command`` on this family (any of its machines): a refused option's
        gap, the command's gap where the family does not run it on any machine, else ``("yes", "")``."""
        command = COMMAND_MODES.get((command, option), command)
        for r in self.refusals:
            for o in r.options:
                if r.command == command and o.flag == option:
                    return o.word, r.message
        if command not in self.targets:
            return self.gaps[command].word, self.gaps[command].reason
        return YES, ""


COMMAND_MODES = {("report", "run"): "report run"}
"""Options that make a command another job (``report RUN`` writes a chain run's page, not a comparison): the
registry's name of that job."""


_FLEET = Gap(NOT_YET, "a fleet file's machines are machine tools (identify from sweeps)")
_DEMO = Gap(NOT_YET, "the demo's part is the grinder's flute")
_BY_POSES = "{given}: only arms and parallel machines are simulated by poses (machine tools: --checks)"
_IDENTIFY = Gap(OTHER_PATH, "calibrate (poses)")
_PARALLEL_TRUTH = ("{given}: a parallel machine's truth has one family and no effects here (leg scales, zero lengths, "
                   "joints); leave it out")
_DIAGNOSE_CHECK = Gap(OTHER_PATH, "calibrate --check (the loop on the held-out check poses)")
_DIAGNOSE = (Refusal("diagnose", (Opt("--alpha", NOT_YET, default=0.01, show_value=True),),
                     "{given}: not used on a machine tool: the closed loop gates each effect on its held-out z "
                     "(errormap/diagnosis/chain_loop.py); leave it out"),)
_CALIBRATE_OTHER = ("{given}: {does} not apply to {what} (see calibrate --help: the options are grouped by machine "
                    "kind); leave {it} out")

def machine_tool_facts(machine) -> dict:
    """The facts of :class:`Facts` a loaded machine tool's axes decide: ``flute_axes`` (the flute path runs on it,
    :func:`compensation.toolpath.runs_flute`) and ``fixed_tool_axis`` (three axes, one of them rotary)."""
    rotary = any(a.kind == "rotary" for a in machine.axes)
    return {"flute_axes": runs_flute(machine), "fixed_tool_axis": len(machine.axes) == 3 and rotary}


_FLUTE_OPTIONS = (Opt("--flute", PHYSICS), *(Opt(f"--{k.replace('_', '-')}", PHYSICS, default=getattr(FLUTE_DEFAULTS, k))
                                             for k in ("turns", "points_per_turn", "radius_mm", "helix_start_deg",
                                                       "helix_end_deg", "lead_law", "px_start_mm")))

MACHINE_TOOL = Family(
    name="machine tool", column="Machine tool",
    kinds={"machine-tool": Facts(tracker_sweeps=True, gcode=True)},
    targets={**dict.fromkeys(("simulate", "sweeps", "featurepoints", "identify", "train", "predict", "benchmark", "demo",
                              "report run"), "chain"),
             **dict.fromkeys(("compensate", "export", "diagnose", "report", "fleet"), "machine tool")},
    gaps={"demo": Gap(NOT_YET, "the demo's part is the flute (the workpiece turned about X by a full-turn A, fed by X "
                           "and one radial linear axis)", unless="flute_axes"),
          "calibrate": Gap(OTHER_PATH, "identify (sweeps), then diagnose (checks)"),
          "register": Gap(OTHER_PATH, "the tracker pose is estimated inside identify with every set-up"),
          "interpolate": Gap(OTHER_PATH, "compensate (axis programs)")},
    refusals=(Refusal("simulate", (Opt("--poses", OTHER_PATH),), _BY_POSES), *_DIAGNOSE,
              Refusal("report", _FLUTE_OPTIONS,
                      "{given}: the flute needs the workpiece turned about X by a full-turn A and one radial "
                      "linear axis beside X; on {name} "
                      "compare the methods on its own --path", unless="flute_axes"),
              Refusal("compensate", (Opt("--compensate-orientation", PHYSICS),),
                      "{given}: the one rotary axis of {name!r} turns the workpiece and none turns the tool axis "
                      "(its three axes place the tool point): there is no tool orientation to compensate; leave it out",
                      when="fixed_tool_axis")),
    machine_facts=machine_tool_facts)

ARM = Family(
    name="serial arm", column="Serial arm",
    kinds={"serial": Facts(poses=True)},
    targets=dict.fromkeys(("simulate", "calibrate", "register", "predict", "compensate", "benchmark"), "arm"),
    gaps={"fleet": _FLEET, "demo": _DEMO, "identify": _IDENTIFY, "diagnose": _DIAGNOSE_CHECK,
          "export": Gap(NOT_YET, "no controller format for an arm's calibration"),
          "sweeps": Gap(OTHER_PATH, "poses spread over every joint (simulate --poses, then calibrate)"),
          "featurepoints": Gap(OTHER_PATH, "the arm's learned stage is fitted on the measured poses inside calibrate"),
          "train": Gap(OTHER_PATH, "the arm's learned stage (a Gaussian process chosen by CV) inside calibrate"),
          "interpolate": Gap(OTHER_PATH, "compensate (joint programs)"),
          "report": Gap(NOT_YET, "one method (Newton): compensate --machine"),
          "report run": Gap(OTHER_PATH, "calibrate writes report.html")},
    refusals=(
        Refusal("simulate", (Opt("--family", NOT_YET, default="default", show_value=True),),
                "{given}: a serial arm's truth has one family (errormap/arm_simulate.py: link, base and tool errors, "
                "sag, backlash); leave it out"),
        Refusal("compensate", (Opt("--work-offsets", PHYSICS), Opt("--tool-table", PHYSICS),
                               Opt("--rapids", PHYSICS, default=DEFAULT_RAPIDS), Opt("--block-delete", PHYSICS),
                               Opt("--arc-tolerance-um", PHYSICS, default=DEFAULT_ARC_TOLERANCE_UM),
                               Opt("--dialect", PHYSICS, default="auto"), Opt("--expand-cycles", PHYSICS),
                               Opt("--lathe-x", PHYSICS), Opt("--subprograms", PHYSICS)),
                "{given}: G-code programs of machine tools only (a serial arm's program is joint angles)"),
        Refusal("compensate", (Opt("--truth", NOT_YET),),
                "{given} is not used on a serial arm ({name}): the true residual of a compensated program is reported "
                "on machine-tool chains only; leave it out (the MODEL residual is written beside the joints)"),
        Refusal("compensate", (Opt("--cluster", NOT_YET), Opt("--address", NOT_YET), Opt("--workers", NOT_YET),
                               Opt("--chunk-points", NOT_YET, default=CHUNK_POINTS),
                               Opt("--max-segment-mm", NOT_YET, default="auto")),
                "{given}: a serial arm's joint program is solved point by point in one process ({name}); "
                "leave {it} out"),
        Refusal("compensate", tuple(Opt(f, OTHER_PATH) for f in ("--temp-c", "--time-s", "--dir-x", "--dir-z",
                                                                  "--dir-a")),
                "{given}: a serial arm's sag and backlash are functions of its joints (computed, not given); "
                "leave {it} out"),
        Refusal("compensate", (Opt("--max-rotary-correction-deg", OTHER_PATH),),
                "{given}: a serial arm's joint limits bound every joint; leave it out"),
        Refusal("compensate", (Opt("--compensate-orientation", NOT_YET),),
                "{given}: not yet on a serial arm (its joint solve corrects the tool point, not its orientation); "
                "leave it out"),
        Refusal("calibrate", tuple(Opt(f, NOT_YET) for f in ("--no-scales", "--scales", "--no-loop", "--no-register",
                                                             "--lever-mm", "--lambda-rule", "--compare-rules")),
                _CALIBRATE_OTHER.replace("{what}", "a serial arm"))))

PARALLEL = Family(
    name="parallel machine", column="Parallel (hexapod, tripod)",
    kinds={"hexapod": Facts(poses=True, platform_orientation=True, paper_paths=True),
           "tripod": Facts(poses=True, sensitivity_study=True)},
    targets=dict.fromkeys(("simulate", "calibrate", "interpolate", "predict", "benchmark"), "parallel"),
    gaps={"fleet": _FLEET, "demo": _DEMO, "identify": _IDENTIFY, "diagnose": _DIAGNOSE_CHECK,
          "compensate": Gap(OTHER_PATH, "interpolate --calibration writes the compensated leg-command program"),
          "export": Gap(NOT_YET, "no controller table (interpolate compensates the leg commands)"),
          "sweeps": Gap(OTHER_PATH, "poses (calibrate: leg lengths, joint positions, scales)"),
          "featurepoints": Gap(NOT_YET, "no learned field of a parallel machine"),
          "train": Gap(NOT_YET, "no learned field of a parallel machine"),
          "register": Gap(OTHER_PATH, "calibrate registers the instrument frame"),
          "report": Gap(NOT_YET, "no comparison of leg-command methods"),
          "report run": Gap(OTHER_PATH, "calibrate writes report.html")},
    refusals=(
        Refusal("simulate", (Opt("--family", NOT_YET, default="default"), Opt("--effect", NOT_YET)), _PARALLEL_TRUTH),
        Refusal("calibrate", (Opt("--no-learned", NOT_YET), Opt("--folds", NOT_YET)),
                _CALIBRATE_OTHER.replace("{what}", "a {kind}")),
        Refusal("predict", (Opt("--band", NOT_YET), Opt("--allow", PHYSICS), Opt("--tracking-uri", NOT_YET),
                            Opt("--units", NOT_YET, default="check")),
                "{given}: not on a parallel machine yet (its model.json holds no prediction band; poses outside "
                "the leg ranges are refused); leave it out"),
        Refusal("interpolate", (Opt("--sensitivity-plot", NOT_YET),),
                "{path}: --sensitivity-plot needs a tripod machine file, got {kind!r}", kinds=("hexapod",))))

FAMILIES = (MACHINE_TOOL, ARM, PARALLEL)
"""Every family, in the order of the columns of docs/reference/features.md."""


def family_of_kind(kind: str) -> Family:
    """The family of the machine kind ``kind`` (a recorded one, e.g. a benchmark row's), bound to it;
    ``ValueError`` for a kind no family holds (every parser's kind has one: tests/test_family_registry.py)."""
    for f in FAMILIES:
        if kind in f.kinds:
            return dataclasses.replace(f, kind=kind)
    raise ValueError(f"machine kind {kind!r} belongs to no family (compensation/app/families.py)")


def refuse_model_family(command: str, src) -> None:
    """Refuse (one line, the registry's gap) a model of a family that does not run ``command``: an arm's or a
    parallel machine's calibration (``src``: :class:`compensation.fields.ModelSource`) given to ``export`` or
    ``report``, which would otherwise be read against the default machine tool."""
    from ..fields import KIND_NAMES
    family = {"arm-model": ARM, "arm-calibration": ARM, "pkm-model": PARALLEL,
              "pkm-calibration": PARALLEL}.get(src.kind)
    if family is not None and command not in family.targets:
        g, name = family.gaps[command], KIND_NAMES[src.kind]
        article = "an" if name[0] in "aeiou" else "a"
        raise UsageError(f"{src.path or src.spec}: {article} {name}: volcomp {command} does not run on a "
                         f"{family.name}: {g.word}: {g.reason}")


def say_read_as(machine) -> None:
    """Say on stderr, in its one line, that the machine file was read into another form (a ``kind = "grinder"``
    file as its chain, ``MachineTool.read_as``); nothing for any other file."""
    import sys
    if getattr(machine, "read_as", ""):
        print(machine.read_as, file=sys.stderr)


def family_of(machine) -> Family:
    """The family of a loaded machine, bound to it (its kind, file, name and facts)."""
    f = family_of_kind(machine.kind)   # a kind = "grinder" file is read as its chain: kind machine-tool
    facts = dataclasses.replace(f.facts, **f.machine_facts(machine)) if f.machine_facts else None
    return dataclasses.replace(f, path=str(getattr(machine, "path", "")), machine_name=getattr(machine, "name", ""),
                               bound_facts=facts)
