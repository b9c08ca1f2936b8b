"""One closing line for the two test tiers of `.ci/run`, from their JUnit XML files.

    python .ci/tiers.py fast.xml slow.xml
    -> 812 passed, 9 skipped in 655.12s (fast tier: 760 passed, 9 skipped in 290.40s; slow tier: 52 passed in 364.72s)

A tier whose file is missing (pytest stopped before writing it) is named as such.
"""
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

KEYS = ("failed", "passed", "skipped", "errors")


def counts(path: Path):
    """``{failed, passed, skipped, errors, seconds}`` of one JUnit file, or None if it is missing."""
    if not path.is_file():
        return None
    c = dict.fromkeys(KEYS, 0)
    c["seconds"] = 0.0
    root = ET.parse(path).getroot()
    for suite in ([root] if root.tag == "testsuite" else list(root.iter("testsuite"))):
        tests, fail, err, skip = (int(suite.get(k, 0)) for k in ("tests", "failures", "errors", "skipped"))
        c["failed"] += fail
        c["errors"] += err
        c["skipped"] += skip
        c["passed"] += tests - fail - err - skip
        c["seconds"] += float(suite.get("time", 0.0))
    return c


def words(c) -> str:
    parts = [f"{c[k]} {k}" for k in KEYS if c[k]] or ["no tests ran"]
    return ", ".join(parts) + f" in {c['seconds']:.2f}s"


def main(argv) -> int:
    tiers = [(name, counts(Path(p))) for name, p in zip(("fast tier", "slow tier"), argv)]
    total = dict.fromkeys(KEYS, 0)
    total["seconds"] = 0.0
    for _, c in tiers:
        for k in total:
            total[k] += c[k] if c else 0
    inner = "; ".join(f"{name}: {words(c) if c else 'no result file'}" for name, c in tiers)
    print(f"{words(total)} ({inner})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
