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
    assert {"Study.run", "Study.tune", "Study.validate", "Study.sweep", "Study.design", "Study.learn",
            "Study.learn_schedule", "load_study", "tune", "validate", "learn_schedule"} <= set(checked), checked


def test_every_floor_types_its_progress_parameter_alike():
    """Below the application layer too, a parameter named ``progress`` is the one type (defined on the ground
    floor, :mod:`piezopreload.core.progress`): it had five signatures there (a line, ``(done, total)``, a count, a
    tick, an optimiser's ``(k, cost, params)``) and the stage runner's own protocol. A bar's callback is ``bar``
    and a counter's ``counter``, each given by a :class:`Progress`."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    found, other = [], []
    for folder in ("core", "models", "artifacts", "design", "tuning", "rig", "reports"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                for arg in (*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs):
                    if arg.arg == "progress":
                        where = f"{path.relative_to(root)}:{node.lineno} {node.name}"
                        found.append(where)
                        text = ast.unparse(arg.annotation) if arg.annotation is not None else "(none)"
                        if text not in ("ProgressLike", "ProgressLike | None"):
                            other.append(f"{where}: {text}")
    assert len(found) >= 10, found
    assert other == [], "progress parameters of another type:\n" + "\n".join(other)


def test_a_lower_floor_step_takes_a_progress_or_a_function():
    """The host check (the rig's floor) says its line to a function and to a :class:`Progress` alike: it took only
    a function, and a Progress given to it was called (a TypeError); a bar for a function gives a line a quarter."""
    from piezopreload.core.progress import bar_of
    from piezopreload.rig.hostcheck import check_host

    seen, out = [], io.StringIO()
    check_host(rate_Hz=1000.0, seconds=0.02, loop="python", progress=seen.append)
    check_host(rate_Hz=1000.0, seconds=0.02, loop="python", progress=Progress(out))
    assert seen[0].startswith("checking this host: 20 wake-ups at 1000 Hz")
    assert out.getvalue() == f"      {seen[0]}\n"
    lines = []
    bar = bar_of(lines.append, "plants")
    for i in range(1, 9):
        bar(i, 8)
    assert [line.split(":")[0].strip() for line in lines] == ["plants"] * 5  # at 0, 1/4, 1/2, 3/4 and 4/4
    assert bar_of(None, "plants") is None
