"""The tree static tools read: the links that show the floors inside the package, and a type check that fails.

A type checker, import-linter and an IDE resolve ``piezopreload.models.metrics`` to ``models/metrics.py`` through the
links committed under ``piezopreload/`` (docs/architecture.md); pyproject's package-dir mapping builds the
wheel. The two must name the same folders, and the type check must see across them: a script that calls a
name a floor does not have, or calls one with the wrong type, turns it red.
"""

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAPPING = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]


@pytest.mark.parametrize("package", sorted(p for p in MAPPING if p != "piezopreload"))
def test_each_mapped_folder_is_linked_from_the_package(package):
    link = ROOT / "piezopreload" / package.split(".", 1)[1]
    assert link.is_symlink(), f"{link.relative_to(ROOT)} is not a link (pyproject maps {package} to {MAPPING[package]})"
    assert link.readlink() == Path("..", MAPPING[package]), f"{link.relative_to(ROOT)} points at {link.readlink()}"
    assert link.resolve() == (ROOT / MAPPING[package]).resolve()


def test_every_folder_under_the_package_is_mapped_for_the_build():
    """A link without its package-dir entry would type-check but be missing from the wheel."""
    links = {f"piezopreload.{p.name}" for p in (ROOT / "piezopreload").iterdir() if p.is_symlink()}
    assert links == set(MAPPING) - {"piezopreload"}


GOOD = '''\
from piezopreload import Study, __version__
from piezopreload.core.errors import InputError
from piezopreload.models.metrics import step_metrics

error: InputError = InputError("a message")
'''

BAD = '''\
from piezopreload.models.metrics import no_such_function  # line 1: a name models does not have
from piezopreload.core.errors import InputError
from piezopreload import Studdy  # line 3: a name the front door does not export (its lazy loading hides none)

error: int = InputError("a message")  # line 5: an error is not an int
'''


@pytest.mark.slow
def test_the_type_check_sees_the_floors_and_fails_on_a_wrong_call(tmp_path):
    """The check CI runs (mypy from the root, pyproject's settings) on a right and a wrong script."""
    (tmp_path / "good_probe.py").write_text(GOOD)
    (tmp_path / "bad_probe.py").write_text(BAD)
    # the repository's own cache, as CI's `mypy -p piezopreload` (run just before the tests) leaves it: mypy checks each
    # cached module's hash, so only the probes are checked afresh (about 2 s against 20 s from an empty cache)
    done = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(ROOT / ".mypy_cache"),
                           "--config-file", str(ROOT / "pyproject.toml"),
                           str(tmp_path / "good_probe.py"), str(tmp_path / "bad_probe.py")],
                          cwd=ROOT, capture_output=True, text=True)
    out = done.stdout + done.stderr
    errors = [line for line in out.splitlines() if "_probe.py:" in line and ": error:" in line]
    assert done.returncode == 1, out
    assert not [e for e in errors if "good_probe.py" in e], out
    assert any("bad_probe.py:1:" in e and "no_such_function" in e and "[attr-defined]" in e for e in errors), out
    assert any("bad_probe.py:3:" in e and "Studdy" in e and "[attr-defined]" in e for e in errors), out
    assert any("bad_probe.py:5:" in e and "[assignment]" in e for e in errors), out
    assert len(errors) == 3, out  # the package's own errors are CI's `mypy -p piezopreload`


def test_the_front_door_lists_each_name_once_for_the_runtime_and_for_static_tools():
    """``__all__``, the lazy map and the TYPE_CHECKING imports name the same things from the same modules."""
    import ast

    import piezopreload

    tree = ast.parse((ROOT / "piezopreload" / "__init__.py").read_text())
    guarded = next(node for node in tree.body if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING")
    static = {alias.name: node.module for node in guarded.body if isinstance(node, ast.ImportFrom)
              for alias in node.names}
    assert static == piezopreload._EXPORTS
    assert set(piezopreload.__all__) == {"__version__", *piezopreload._EXPORTS}
    for name in piezopreload.__all__:
        assert getattr(piezopreload, name) is not None, name


def test_the_front_door_exports_every_result_its_steps_give_back():
    """Each type a front-door name returns (a function, or a public method or property of an exported type), and what
    those results' methods return in turn, is exported, so a script can name what it holds (``pp.StudyResult``).
    The physics floor's types (``piezopreload.models``, reached through a gain set's controller) stop the walk."""
    import inspect
    import re
    import sys

    import piezopreload

    def returned(obj):
        members = [obj] if not inspect.isclass(obj) else [
            getattr(obj, n) if not isinstance(inspect.getattr_static(obj, n), property)
            else inspect.getattr_static(obj, n).fget for n in dir(obj) if not n.startswith("_")]
        for m in members:
            try:
                yield from re.findall(r"\b([A-Z]\w+)\b", str(inspect.signature(m).return_annotation))
            except (TypeError, ValueError):
                continue

    def ours(name):
        for module in [m for n, m in list(sys.modules.items()) if n.startswith("piezopreload.")]:
            obj = getattr(module, name, None)
            if inspect.isclass(obj) and obj.__module__.startswith("piezopreload."):
                return obj
        return None

    exported = {n: getattr(piezopreload, n) for n in piezopreload.__all__ if n != "__version__"}
    frontier, missing = list(exported.values()), set()
    while frontier:
        for name in returned(frontier.pop()):
            obj = ours(name)
            if obj is None or name in exported or name in missing or obj.__module__.startswith("piezopreload.models."):
                continue
            missing.add(name)
            frontier.append(obj)
    assert not missing, f"reachable from the front door but not exported: {sorted(missing)}"


def _lint_imports(root: Path) -> str:
    """import-linter's report on the package laid out under ``root`` (pyproject's contracts; the package found there
    first, before the editable install's)."""
    import os

    lint = Path(sys.executable).with_name("lint-imports")
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run([str(lint)], cwd=root, env=env, capture_output=True, text=True)
    return done.stdout + done.stderr


@pytest.mark.slow
def test_the_import_contract_orders_the_application_layer_and_keeps_the_front_door_unimported(tmp_path):
    """The contract CI runs (``.ci/lint_imports.py``) on a copy of the tree: kept as it is; broken by a step of the
    application layer imported from beneath it (the knot: the study's specification importing the steps that take a
    study) and by a module importing the front door."""
    import shutil

    for name in ("pyproject.toml", *sorted({*MAPPING.values(), "piezopreload"})):
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, tmp_path / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.so", "build"))
        else:
            shutil.copy(source, tmp_path / name)
    kept = _lint_imports(tmp_path)
    assert "0 broken" in kept, kept
    spec, pipeline = tmp_path / "piezopreload" / "spec.py", tmp_path / "piezopreload" / "pipeline.py"
    spec.write_text(spec.read_text() + "\n\ndef _probe() -> None:\n    from piezopreload.steps import tune  # noqa\n")
    pipeline.write_text(pipeline.read_text() + "\n\ndef _probe() -> str:\n    from piezopreload import __version__\n"
                                                "    return __version__\n")
    broken = _lint_imports(tmp_path)
    assert "2 broken" in broken, broken
    assert "piezopreload.spec -> piezopreload.steps" in broken, broken
    assert "piezopreload.pipeline -> piezopreload (l." in broken, broken
