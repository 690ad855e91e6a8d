"""One declared type per concept (issue 42's leftovers): no result forwards another's fields, the records that
carry the thermal figures, the gain schedule and the rig run's safety and pushes, the enums that choose behaviour
in the study's tables, and the study's verbs documented once."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from piezopreload.artifacts.manifest import StudyRef
from piezopreload.models.controller import PIDGains
from piezopreload.results import StudyReproduction
from piezopreload.tuning.compare import PublishedRow

ROOT = Path(__file__).parents[1]


def _forwarders(source: str) -> list[str]:
    """The properties whose body (past a docstring) only returns an attribute of one of the object's own fields
    (``return self.field.attr``): a result that forwards what another result holds."""
    found = []
    for cls in (n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef)):
        for fn in cls.body:
            if not (isinstance(fn, ast.FunctionDef)
                    and any(isinstance(d, ast.Name) and d.id == "property" for d in fn.decorator_list)):
                continue
            body = [s for s in fn.body if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))]
            value = body[0].value if len(body) == 1 and isinstance(body[0], ast.Return) else None
            if (isinstance(value, ast.Attribute) and isinstance(value.value, ast.Attribute)
                    and isinstance(value.value.value, ast.Name) and value.value.value.id == "self"):
                found.append(f"{cls.name}.{fn.name} -> {ast.unparse(value)}")
    return found


def test_the_forwarder_check_can_fail():
    source = '''
class Outer:
    @property
    def rows(self):
        """The rows."""
        return self.comparison.rows

    @property
    def within(self):
        return all(r.ok for r in self.rows)
'''
    assert _forwarders(source) == ["Outer.rows -> self.comparison.rows"]


def test_the_study_results_forward_nothing():
    """What the study's simulating steps return holds its own numbers: no property hands on another result's."""
    found = _forwarders((ROOT / "piezopreload" / "results.py").read_text(encoding="utf-8"))
    assert not found, "forwarding properties:\n" + "\n".join(found)


def _reproduction(within: tuple[bool, ...]) -> StudyReproduction:
    rows = tuple(PublishedRow("pid", m, 0.1, 0.1 * (1.1 if ok else 1.5), 1.1 if ok else 1.5, ok, (0.1, 0.2))
                 for m, ok in zip(("rise_s", "peak_s", "settling_s"), within, strict=True))
    return StudyReproduction(StudyRef("s.toml", "0" * 64, "s"), PIDGains(Kc=0.1, Ti_s=0.08, Td_s=0.0), "s", 0.5,
                             "force", "paper", (0.0, 100.0), rows, {"pid": 1.5}, {"rms_pct": 1.0, "max_pct": 2.0},
                             3, 0.25)


def test_a_reproduction_holds_its_rows_and_prints_the_same_keys():
    """``reproduce --json`` prints the keys it printed when the comparison was a record of its own."""
    rep = _reproduction((True, False, True))
    assert list(rep.to_dict()) == ["study", "gains", "band_N", "signal", "published", "step", "feedforward_fit",
                                   "rows", "overshoot_N", "all_within_25pct", "repeats", "seconds"]
    assert rep.to_dict()["all_within_25pct"] is False and _reproduction((True,) * 3).all_within_25pct
    assert rep.row("pid", "peak_s").ratio == 1.5 and rep.repeats == 3
    with pytest.raises(KeyError, match="pid/rise_s, pid/peak_s, pid/settling_s"):
        rep.row("ff+pid", "rise_s")
