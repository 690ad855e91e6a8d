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


def test_a_function_gets_each_line_and_bars_a_line_a_quarter():
    lines: list[str] = []
    p = Progress(lines=lines.append)
    p.stage(1, 2, "tune", "the PID")
    p.say("tuned")
    bar = p.bar("plants")
    for i in range(1, 5):
        bar(i, 4)
    p.counter("iterations", every=2)(2)
    assert lines[:2] == ["[1/2] tune: the PID", "      tuned"]
    assert [line.split(" (")[0].strip() for line in lines[2:]] == [
        "plants: 1/4", "plants: 2/4", "plants: 3/4", "plants: 4/4", "iterations: 2"]
    assert not any("\r" in line or "\n" in line for line in lines)


def test_every_step_takes_a_function_or_a_progress_and_refuses_anything_else():
    import pytest

    from piezopreload.core.errors import InputError
    from piezopreload.progress import as_progress, say_of

    p = Progress(io.StringIO())
    assert as_progress(p) is p and say_of(p) == p.say
    assert as_progress(print).lines is print and say_of(print) is print
    assert say_of(None) is None and as_progress(None).stream is not None
    for bad in ("stderr", 3):
        with pytest.raises(InputError, match="progress must be a function taking a line"):
            as_progress(bad)  # type: ignore[arg-type]
        with pytest.raises(InputError, match="progress must be a function taking a line"):
            say_of(bad)  # type: ignore[arg-type]


def test_the_api_types_every_progress_parameter_alike():
    """Each public step that reports progress takes the one type (a function or a Progress), so no caller finds
    one that takes only a function and another that needs the object (``study.run(progress=print)``)."""
    import inspect

    import piezopreload as pp
    from piezopreload import pipeline, sweep
    from piezopreload import steps as study_steps

    steps = [getattr(pp.Study, name) for name in dir(pp.Study) if not name.startswith("_")]
    steps += [getattr(study_steps, name) for name in study_steps.__all__]
    steps += [getattr(pp.TuningResult, name) for name in dir(pp.TuningResult) if not name.startswith("_")]
    steps += [pp.load_study, pipeline.run_study, pipeline.rerender_report, sweep.sweep, sweep.rerender_sweep_report]
    checked = []
    for step in steps:
        if not callable(step) or "progress" not in inspect.signature(step).parameters:
            continue
        annotation = inspect.signature(step).parameters["progress"].annotation  # the source's text (PEP 563)
        assert annotation == "ProgressLike | None", f"{step.__qualname__}: progress is {annotation}"
        checked.append(step.__qualname__)
    # Study's steps (design, learn, ...: the functions of piezopreload.steps; the parsed study itself runs none)
    assert {"Study.run", "Study.tune", "Study.validate", "Study.sweep", "Study.design", "Study.learn",
            "Study.learn_schedule", "load_study", "tune", "validate", "learn_schedule"} <= set(checked), checked
