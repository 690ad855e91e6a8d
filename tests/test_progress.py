"""Progress on standard error: bars and counters redraw in place on a terminal, print lines elsewhere."""

import io

from piezopreload.progress import Progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_bars_redraw_in_place_and_the_next_message_ends_a_counter():
    out = _Terminal()
    p = Progress(out, width=4)
    bar = p.bar("plants")
    for i in range(1, 5):
        bar(i, 4)
    count = p.counter("iterations")
    count(1)
    count(2)
    p.say("tuned")
    lines = out.getvalue().split("\n")
    assert lines[0].startswith("\r      plants [#...] 1/4") and lines[0].count("\r") == 4
    assert "plants [####] 4/4" in lines[0]
    assert lines[1].startswith("\r      iterations: 1") and "\r      iterations: 2" in lines[1]
    assert lines[2] == "      tuned" and lines[3] == ""


def test_into_a_file_bars_print_a_line_a_quarter_and_counters_every_nth():
    out = io.StringIO()
    p = Progress(out)
    bar = p.bar("plants")
    for i in range(1, 9):
        bar(i, 8)
    count = p.counter("iterations", every=2)
    for k in range(1, 6):
        count(k)
    lines = out.getvalue().splitlines()
    assert [line.split(" (")[0].strip() for line in lines] == [
        "plants: 1/8", "plants: 2/8", "plants: 4/8", "plants: 6/8", "plants: 8/8", "iterations: 2", "iterations: 4"]
    assert "\r" not in out.getvalue()


def test_quiet_prints_nothing():
    out = _Terminal()
    p = Progress(out, quiet=True)
    p.stage(1, 2, "tune", "x")
    p.bar("b")(1, 1)
    p.counter("c")(1)
    assert out.getvalue() == ""
