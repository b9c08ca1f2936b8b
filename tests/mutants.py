"""Seeded edits of a text file, the way files get damaged: the one mutation helper of the tests that feed volcomp
damaged programs and input files (tests/test_gcode_mutants.py, tests/test_input_mutants.py)."""
from __future__ import annotations

import random
import re

NUMBER = re.compile(r"-?\d*\.?\d+(?:[eE][-+]?\d+)?")


def mutate(text: str, rng: random.Random, chars: str, values, extra) -> str:
    """1 to 4 edits of ``text``, each one of: a character deleted; a character of ``chars`` inserted; a number
    replaced by one of ``values``; a line duplicated, deleted or swapped with another; the text cut short; or
    ``extra(lines, rng)`` (the caller's own edit of the list of lines, in place)."""
    for _ in range(rng.randint(1, 4)):
        lines = text.split("\n")
        op = rng.randrange(8)
        if op == 0 and text:
            i = rng.randrange(len(text))
            text = text[:i] + text[i + 1:]
        elif op == 1:
            i = rng.randrange(len(text) + 1)
            text = text[:i] + rng.choice(chars) + text[i:]
        elif op == 2:
            nums = list(NUMBER.finditer(text))
            if nums:
                m = rng.choice(nums)
                text = text[:m.start()] + rng.choice(values) + text[m.end():]
        elif op == 6 and text:
            text = text[:rng.randrange(len(text))]
        elif op in (3, 4, 5, 7):
            if op == 3:
                i = rng.randrange(len(lines))
                lines.insert(i, lines[i])
            elif op == 4 and len(lines) > 1:
                del lines[rng.randrange(len(lines))]
            elif op == 5 and len(lines) > 1:
                i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
                lines[i], lines[j] = lines[j], lines[i]
            elif op == 7:
                extra(lines, rng)
            text = "\n".join(lines)
    return text
