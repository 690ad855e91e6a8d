"""The study's steps: the parsed study (``StudySpec``) holds nothing solved and runs nothing; the steps are the
functions of ``piezopreload.steps``, what they solve is kept in a ``Solved``; ``tune()`` calls only down the floors;
the tune step returns the tuning artifact itself."""

from __future__ import annotations

import dataclasses
import sys
import tomllib
from pathlib import Path

import pytest

import piezopreload as pp
from piezopreload import steps
from piezopreload.spec import StudySpec

ROOT = Path(__file__).resolve().parent.parent
QUIET = {"progress": lambda _m: None}


def test_the_spec_is_the_parsed_study_and_nothing_else():
    """No cache among its fields, no step among its methods: a spec of the machine axis is the same object after its
    design is solved for a step, and a second Solved solves it again (nothing was kept in the spec)."""
    names = {f.name for f in dataclasses.fields(StudySpec)}
    assert "_kept" not in names and not any("cache" in n or "kept" in n for n in names), names
    for step in ("design", "identify_feedforward", "measured_loop", "learn", "track_schedule", "solved_plant",
                 "with_design", "plant", "designed_plant", "preload_schedule"):
        assert not hasattr(StudySpec, step), f"StudySpec.{step} is a step (or what one solves), not the parsed study"
    spec = StudySpec.load("machine_axis", **QUIET)
    before = dict(vars(spec))
    solved = steps.Solved(spec)
    point = solved.design_point()
    assert dict(vars(spec)).keys() == before.keys() and all(vars(spec)[k] is before[k] for k in before)
    assert steps.Solved(spec).point is None and solved.point is point  # the spec kept nothing; the Solved did


def test_a_study_keeps_what_its_steps_solved_outside_the_spec():
    """``Study`` holds one Solved; its copies keep the design where it is the same and a given design is taken as
    given (not solved)."""
    axis = pp.load_study(**QUIET)
    assert isinstance(axis.solved, steps.Solved) and axis.solved is axis.solved
    axis.solved.design_point()
    same = axis.replace(simulation={"seed": 3})
    assert same.solved.point is axis.solved.point and same.solved is not axis.solved
    other = axis.replace(design={"failsafe_load_N": 800.0})
    assert other.solved.point is None
    given = axis.with_design(axis.solved.point, "cd" * 32)
    assert given.solved.point is axis.solved.point and given.designed_plant.design_sha256 == "cd" * 32


def test_the_schedule_is_learned_by_its_own_step_not_by_a_name():
    """``learn`` takes the study's references or a Reference; along the schedule is ``learn_schedule``."""
    import inspect

    assert "schedule" not in inspect.signature(pp.Study.learn_schedule).parameters
    with pytest.raises(pp.InputError, match="learn_schedule"):
        pp.load_study("paper2021", **QUIET).learn(reference="schedule")


def test_one_tuning_result_the_solver_returns_the_artifacts_record():
    """``pp.TuningResult`` is the tuning artifact (``tuning.json``); ``tune_pid`` returns its ``TuningSolve``; no
    other class of that name is left on any floor."""
    import ast

    from piezopreload.artifacts import tuning as artifact
    from piezopreload.tuning import pid

    assert pp.TuningResult is artifact.TuningResult
    assert pid.tune_pid.__annotations__["return"] == "TuningSolve" and not hasattr(pid, "TuningResult")
    defined = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*.py") if ".venv" not in p.parts and "tests" not in p.parts
               for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
               if isinstance(node, ast.ClassDef) and node.name == "TuningResult"]
    assert sorted(set(defined)) == ["artifacts/tuning.py"], defined


_ROOTS = {"core", "models", "artifacts", "design", "tuning", "rig", "reports"}


class _CallFloors:
    """A profile hook: each call from one of the package's modules into another, its modules placed on their floors
    (pyproject's import contract); ``up`` the calls into a higher floor, ``front`` the front door's callers."""

    def __init__(self) -> None:
        layers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]["layers"]
        self.floors = {name.strip(): i for i, layer in enumerate(reversed(layers)) for name in layer.split("|")}
        self.seen: dict[str, tuple[str, int] | None] = {}
        self.up: set[tuple[str, str, str]] = set()
        self.front: set[str] = set()

    def place(self, filename: str) -> tuple[str, int] | None:
        if filename not in self.seen:
            try:
                parts = Path(filename).resolve().relative_to(ROOT).with_suffix("").parts
            except ValueError:
                parts = ()
            if parts and parts[0] == "piezopreload":
                parts = parts[1:]
            self.seen[filename] = None if not parts or parts[0] not in self.floors else (
                ".".join(parts) if parts[0] in _ROOTS else "piezopreload." + ".".join(parts), self.floors[parts[0]])
        return self.seen[filename]

    def __call__(self, frame, event, arg):
        if event != "call" or (callee := self.place(frame.f_code.co_filename)) is None:
            return
        back = frame.f_back
        while back is not None and self.place(back.f_code.co_filename) is None:  # through numpy, casadi, ...
            back = back.f_back
        if back is None:
            return
        caller = self.place(back.f_code.co_filename)
        assert caller is not None
        if caller[0].startswith("piezopreload."):
            self.front.add(caller[0])
        if callee[1] > caller[1]:
            self.up.add((caller[0], callee[0], frame.f_code.co_qualname))


@pytest.mark.slow
def test_tune_calls_only_down_the_floors():
    """``study.tune()`` on the paper's study, followed call by call (a profile hook): every call from one of the
    package's modules into another goes to its own floor or a lower one, except the rules and the step functions
    ``core`` is handed (``check_fields``' rules, the compiled runner's callback): a function passed down, not a
    module calling up. The front door it passes through is the study, the steps, and the spec's tables."""
    calls = _CallFloors()
    study = pp.load_study("paper2021", **QUIET)
    sys.setprofile(calls)
    try:
        study.tune(**QUIET)
    finally:
        sys.setprofile(None)
    passed_down = {(c, m, q) for c, m, q in calls.up if c.startswith("core.") and not m.startswith("piezopreload")}
    assert calls.up == passed_down, sorted(calls.up - passed_down)
    assert calls.front <= {"piezopreload.study", "piezopreload.steps", "piezopreload.spec", "piezopreload.tables",
                           "piezopreload.progress"}, calls.front
