"""Check the import contract (pyproject's [tool.importlinter]) on the tree as it is.

Each folder that pyproject's [tool.setuptools.package-dir] maps into the namespace is linked from
piezopreload/ (piezopreload/core -> ../core, ...), so import-linter walks the package where it stands.
A checkout without those links (git on a system without symbolic links writes each link as a small
text file) would hide the floors from it: that is refused by name instead of checked half.
"""

import subprocess
import sys
import tomllib
from pathlib import Path

root = Path(__file__).resolve().parent.parent
config = tomllib.loads((root / "pyproject.toml").read_text())
mapping = config["tool"]["setuptools"]["package-dir"]
missing = [f"piezopreload/{package.split('.', 1)[1]} -> ../{folder}" for package, folder in sorted(mapping.items())
           if package != "piezopreload"
           and not (root / "piezopreload" / package.split(".", 1)[1] / "__init__.py").is_file()]
if missing:
    sys.exit(f"error: {', '.join(missing)}: these links are not folders in this checkout (check it out with "
             "symbolic links, see docs/architecture.md), so the import contract cannot see those floors")
lint = Path(sys.executable).with_name("lint-imports")
sys.exit(subprocess.run([str(lint)], cwd=root).returncode)  # it reads pyproject.toml from the root
