"""Each public name once: no two public classes of the package share a name, and a renamed export still resolves."""

import ast
import collections
from pathlib import Path

import piezopreload as pp

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ("core", "models", "artifacts", "design", "tuning", "rig", "reports", "piezopreload")


def _public_classes() -> dict[str, list[str]]:
    found = collections.defaultdict(list)
    for folder in FLOORS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if "_build" in path.parts:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    found[node.name].append(str(path.relative_to(ROOT)))
    return found


def test_no_two_public_classes_share_a_name():
    """A reader who meets ``Record``, ``Table``, ``PassRecord`` or ``WorstCase`` meets one class (there were two of
    each: the measured record and the records' base, the study file's table and the report's, a learning pass and a
    margin pass, the robust design's corners and a gain set's Monte Carlo worst case)."""
    twice = {name: where for name, where in _public_classes().items() if len(where) > 1}
    assert twice == {}, f"public classes defined more than once: {twice}"


def test_the_measured_record_keeps_its_former_front_door_name():
    """``pp.MeasuredRecord`` is what ``pp.read_record`` returns; ``pp.Record``, its name before, still resolves to it
    so that existing scripts run, but is no longer listed."""
    assert pp.Record is pp.MeasuredRecord
    assert "MeasuredRecord" in pp.__all__ and "Record" not in pp.__all__
    assert pp.MeasuredRecord.__name__ == "MeasuredRecord"
