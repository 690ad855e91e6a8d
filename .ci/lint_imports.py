"""Check the import contract (pyproject's [tool.importlinter]) on the package as it installs.

The repository maps its top-level folders into the one namespace (pyproject's
[tool.setuptools.package-dir]); an editable install resolves them through an import hook
that import-linter cannot walk. So lay the package out as a wheel would, in a temporary
folder, and run lint-imports on that.
"""

import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

root = Path(__file__).resolve().parent.parent
config = tomllib.loads((root / "pyproject.toml").read_text())
mapping = config["tool"]["setuptools"]["package-dir"]
with tempfile.TemporaryDirectory() as tmp:
    for package, folder in sorted(mapping.items()):
        target = Path(tmp, *package.split("."))
        shutil.copytree(root / folder, target, ignore=shutil.ignore_patterns("__pycache__"), dirs_exist_ok=True)
    lint = Path(sys.executable).with_name("lint-imports")
    done = subprocess.run([str(lint), "--config", str(root / "pyproject.toml")], cwd=tmp,
                          env={"PYTHONPATH": tmp, "PATH": "/usr/bin:/bin"})
sys.exit(done.returncode)
