"""Draw the README's figure from a run of the default study: ``python docs/readme_figure.py piezopreload-out``.

It is the report's figure of the designed system along its preload schedule (the planned and the
achieved preload, the rigidity under the cutting load against the requirement, the deflection
against its limit), read from the run's ``system/system.json`` and written to
``docs/_static/system.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from piezopreload.artifacts.system import SystemRecord
from piezopreload.reports.figures import system_tracking


def main(out: str) -> Path:
    record = SystemRecord.load(Path(out) / "system" / "system.json")
    s = record.series
    fig = system_tracking(s.time_s, s.planned_N, s.achieved_N, s.rigidity_N_per_um, s.required_N_per_um, s.cutting,
                          s.deflection_um, record.numbers.deflection_limit_um)
    path = Path(__file__).parent / "_static" / "system.png"
    path.parent.mkdir(exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "piezopreload-out")
