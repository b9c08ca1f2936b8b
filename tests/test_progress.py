"""errormap.progress: a bar on a terminal, nothing when stderr is redirected (clean CI logs)."""
import io

from errormap.progress import Progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_no_output_off_a_terminal():
    s = io.StringIO()
    p = Progress(3, "solve", stream=s)
    p.update()
    p.update(2, extra="file.nc")
    assert s.getvalue() == "" and not p.enabled and p.done == 3


def test_bar_on_a_terminal_ends_its_line():
    s = _Terminal()
    p = Progress(3, "solve", stream=s, every_s=0.0)
    p.update(3, extra="file.nc")
    out = s.getvalue()
    assert "solve" in out and "3/3" in out and "file.nc" in out and out.endswith("\n")


def test_disabled_draws_nothing_on_a_terminal():
    s = _Terminal()
    p = Progress(2, "x", stream=s, enabled=False)
    p.update(2)
    assert s.getvalue() == ""
