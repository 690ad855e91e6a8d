"""Each module keeps its private members to itself (the architecture's floors, docs/ARCHITECTURE: one owner each).

A name that starts with one underscore is its module's business. Over every module of the package's
floors (core, models, artifacts, design, tuning, rig, reports and the front door), read from the
source's syntax tree:

- no module reads or writes a private attribute (``x._name``, or ``getattr(x, "_name")``) of an
  object other than ``self`` or ``cls``, unless the module itself defines that name (a function
  or class of that name, a name it assigns, or ``self._name = ...``): a class comparing its own
  instances, or a record class calling its own hook, stays inside the module that owns the name;
  writing ``other._name = ...`` defines nothing (it is reaching in too);
- no module imports a private name (``from m import _name``) from another module.

A few names are private by convention of another library's protocol and are read as such (see
``ALLOWED``). What is still to do is listed in ``KNOWN`` with the reason, and goes when it is done.
"""

from __future__ import annotations

import ast
import os
import re
from pathlib import Path

import pytest

import piezopreload

#: the package's floors, lowest first (piezopreload: the front door's own modules)
FLOORS = ("core", "models", "artifacts", "design", "tuning", "rig", "reports", "piezopreload")

#: private by another library's convention, read as that library says
ALLOWED = {
    # namedtuple's public API is spelt with one underscore so that it cannot clash with a field's name
    "_fields", "_replace", "_asdict", "_make",
}
#: (object, attribute) pairs allowed: os._exit ends a child process without running the parent's cleanup (the
#: served rig's server process, when its supervisor has died)
ALLOWED_ON = {("os", "_exit")}
#: IPython's display protocol (_repr_html_, _repr_markdown_, ...): a result shows another result's HTML inside its own
DISPLAY_PROTOCOL = re.compile(r"^_repr_[a-z]+_$")

#: (module, name) reads still to remove, each with its reason
KNOWN: set[tuple[str, str]] = set()


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _defined(tree: ast.AST) -> set[str]:
    """The names a module defines: functions, classes, the names it assigns and the attributes it assigns on
    ``self`` or ``cls``."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            out.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _own(node.value):
            out.add(node.attr)
    return out


def _own(value: ast.expr) -> bool:
    return isinstance(value, ast.Name) and value.id in ("self", "cls", "mcs")


def _allowed(value: ast.expr, name: str) -> bool:
    if name in ALLOWED or DISPLAY_PROTOCOL.match(name):
        return True
    return isinstance(value, ast.Name) and (value.id, name) in ALLOWED_ON


def problems(source: str, module: str) -> list[str]:
    """What ``source`` (the module ``module``) reads or imports of other modules' private members.

    Returns
    -------
    list of str
        ``module:line: what``, one per read or import; empty when the module keeps to its own.
    """
    tree = ast.parse(source)
    defined = _defined(tree)
    out = []

    def read(node: ast.AST, value: ast.expr, name: str, shown: str) -> None:
        if not _private(name) or _own(value) or name in defined or _allowed(value, name):
            return
        if (module, name) in KNOWN:
            return
        out.append(f"{module}:{node.lineno}: {shown}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            read(node, node.value, node.attr, ast.unparse(node))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "hasattr", "setattr", "delattr") and len(node.args) >= 2
              and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)):
            read(node, node.args[0], node.args[1].value, ast.unparse(node))
        elif isinstance(node, ast.ImportFrom):
            names = [a.name for a in node.names if _private(a.name)]
            if names:
                out.append(f"{module}:{node.lineno}: from {'.' * node.level}{node.module or ''} import "
                           f"{', '.join(names)}")
    return out


def _modules() -> list[tuple[str, Path]]:
    """Every module of the floors as ``(floor/relative/path.py, path)``; the front door's links to the floors are
    followed once, as the floors themselves."""
    package = Path(piezopreload.__file__).parent
    found = []
    for floor in FLOORS:
        top = package if floor == "piezopreload" else (package / floor).resolve()
        for here, dirs, files in os.walk(top):  # symbolic links to directories are not followed
            dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "_build"))
            for f in sorted(files):
                if f.endswith(".py"):
                    path = Path(here) / f
                    found.append((f"{floor}/{path.relative_to(top).as_posix()}", path))
    return found


MODULES = _modules()


def test_the_floors_have_modules_to_check():
    names = {m for m, _ in MODULES}
    assert len(MODULES) > 100, len(MODULES)
    for expected in ("core/records.py", "rig/executor.py", "rig/pyloop.py", "design/preload.py",
                     "piezopreload/spec.py", "piezopreload/cli/rig.py"):
        assert expected in names, f"{expected} not among the modules checked"


@pytest.mark.parametrize("module, path", MODULES, ids=[m for m, _ in MODULES])
def test_no_module_reads_another_modules_private_members(module, path):
    found = problems(path.read_text(encoding="utf-8"), module)
    assert not found, "private members of other modules read:\n" + "\n".join(found)


def test_the_known_reads_are_still_there():
    """An entry of KNOWN that is gone must leave the list (a list of exceptions that outlives them hides new ones)."""
    for module, name in KNOWN:
        path = dict(MODULES)[module]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        reads = [n for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr == name and not _own(n.value)]
        assert reads, f"{module} no longer reads .{name} of another object: remove it from KNOWN"


def test_the_check_finds_what_it_forbids():
    """The check can fail: each kind of read it forbids, in a module of its own, is found; the allowed ones are not."""
    source = '''
from piezopreload.models.ballscrew import _rigidity, nut_forces
from .figures import _figure
import os


class Own:
    def __init__(self):
        self._mine = 1

    def __eq__(self, other):
        return other._mine == self._mine


def loop(ex, point, result):
    ex._pending = None
    ex._log_row((1, 2))
    step = getattr(ex.step, "_fn", None)
    point = point._replace(x=1)
    html = result._repr_html_()
    os._exit(0)
    return ex.__class__, step, html, point
'''
    found = problems(source, "<example>")
    assert sorted(f.split(": ", 1)[1] for f in found) == sorted([
        "from piezopreload.models.ballscrew import _rigidity",
        "from .figures import _figure",
        "ex._pending",
        "ex._log_row",
        "getattr(ex.step, '_fn', None)",
    ]), found
    # a name the module gives its own objects (self._pending) is the module's own, read on another of them too
    own = "class Ex:\n    def __init__(self):\n        self._pending = 1\n\ndef f(ex):\n    return ex._pending\n"
    assert not problems(own, "<example>")
    assert problems("def f(ex):\n    return ex._pending\n", "<example>") == ["<example>:2: ex._pending"]
