"""Seeded inputs shared by the machine-tool chain tests."""
from __future__ import annotations

import numpy as np

FAR_MM = 5.0
"""'Far' from the lathe's spindle axis: |X| ≥ 5 mm (see tests/test_chain_rotary_guard.py)."""
NEAR_MM = 0.5
"""'Near' the lathe's spindle axis: |X| < 0.5 mm (where Newton may swing C)."""


def lathe_targets(mt, n, seed, near=False):
    """Seeded programmed axes (n, 3) of ``lathe-xzc`` (X mm, Z mm, C deg) inside the strokes, C on ±1
    extra turns, and their nominal tool points (n, 3) mm: ``near`` puts |X| < NEAR_MM, otherwise
    |X| ≥ FAR_MM (points closer are pushed out to FAR_MM on their side)."""
    rng = np.random.default_rng(seed)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, 3))
    if near:
        ax[:, 0] = rng.uniform(-NEAR_MM, NEAR_MM, n)
    else:
        ax[:, 0] = np.where(np.abs(ax[:, 0]) < FAR_MM, np.sign(ax[:, 0] + 1e-12) * FAR_MM, ax[:, 0])
    ax[:, 2] += rng.integers(-1, 2, n) * 360.0  # programs on other turns of C
    return ax, mt.nominal(ax)


def axes_beyond_strokes(mt, rng, n, margin, turns):
    """Random axes (n, k) of machine ``mt`` uniform over each stroke widened by ``margin`` × its span on
    both sides, full-turn axes moved by a random whole number of turns in ``[-turns, turns]`` (360°
    each); drawn from the Generator ``rng`` (the strokes first, then each full-turn axis in order)."""
    span = mt.stroke_hi - mt.stroke_lo
    ax = rng.uniform(mt.stroke_lo - margin * span, mt.stroke_hi + margin * span, (n, len(mt.axes)))
    for j, a in enumerate(mt.axes):
        if a.full_turn:
            ax[:, j] += 360.0 * rng.integers(-turns, turns + 1, n)
    return ax


OLD_GRINDER_FILE = __import__("pathlib").Path(__file__).parent / "data" / "machines" / "grinder_kind_grinder.toml"
"""The built-in grinder's file in the older ``kind = "grinder"`` schema (read as its chain)."""


def grinder_variant(geometry=None, strokes=None, targets=None, edit=None, sha_suffix: str = "-variant"):
    """The built-in grinder with some of its ``kind = "grinder"`` file's geometry, strokes or targets changed,
    read through the one adapter (:mod:`errormap.grinder_file`); ``edit(doc)`` may change the chain document
    before it is compiled (e.g. a rotary joint's ``direction``). The sha256 says it is another file."""
    import tomllib
    from errormap.grinder_file import check_grinder_chain, grinder_chain_document, read_grinder
    from errormap.machine_tool import parse_machine_tool
    doc = tomllib.loads(OLD_GRINDER_FILE.read_text(encoding="utf-8"))
    doc["geometry"].update(geometry or {})
    doc["strokes"].update({k: list(v) for k, v in (strokes or {}).items()})
    doc["targets"].update({k: np.asarray(v, float).tolist() for k, v in (targets or {}).items()})
    chain = grinder_chain_document(read_grinder(doc, OLD_GRINDER_FILE))
    if edit is not None:
        edit(chain)
    mt = parse_machine_tool(chain, OLD_GRINDER_FILE, "grinder" + sha_suffix)
    check_grinder_chain(mt, OLD_GRINDER_FILE)
    return mt


def central_jacobian(field, axes, h: float = 1e-4) -> np.ndarray:
    """Central differences of ``field.predict`` in each axis column, (n, 3, k): the tests' reference
    Jacobian."""
    axes = np.asarray(axes, dtype=float)
    J = np.empty((len(axes), 3, axes.shape[1]))
    for j in range(axes.shape[1]):
        ap, am = axes.copy(), axes.copy()
        ap[:, j] += h
        am[:, j] -= h
        J[:, :, j] = (field.predict(ap) - field.predict(am)) / (2 * h)
    return J
