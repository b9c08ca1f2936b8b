"""The plain-line fast path of :func:`compensation.gcode.tokenize` (issue 20) reads every line
exactly as the general word loop does: same words (letter, value, text, columns) or the same
refusal (column, message), on random lines mixing plain words with what the loop refuses or
reads specially (E and O words, exponents, blanks inside numbers, huge numbers, bare signs)."""
import random
import re

import compensation.gcode as g

N_LINES = 20_000  # random lines; about a fifth take the fast path (checked below)


def _read(body, fast):
    saved = g._PLAIN_LINE
    g._PLAIN_LINE = saved if fast else re.compile(r"(?!)")  # a pattern that never matches
    try:
        return ("ok", g.tokenize(body))
    except g._Refuse as exc:
        return ("refuse", exc.col, exc.msg)
    finally:
        g._PLAIN_LINE = saved


def test_fast_path_reads_as_the_general_loop():
    rnd = random.Random(20)
    letters = "XZAFGMSTNxzafgmEeOo"
    seps = ["", " ", "  ", "\t", "\r"]
    nums = ["1", "-1.5", "+.5", "5.", "007", "12345678901234567890", "1" * 400, "1 2", ". 5", "1e5", "-", "."]
    fast = 0
    for _ in range(N_LINES):
        body = rnd.choice(seps) + "".join(rnd.choice(letters) + rnd.choice(nums) + rnd.choice(seps)
                                          for _ in range(rnd.randint(1, 4)))
        fast += bool(g._PLAIN_LINE.fullmatch(body))
        assert _read(body, True) == _read(body, False), repr(body)
    assert fast > N_LINES // 10
