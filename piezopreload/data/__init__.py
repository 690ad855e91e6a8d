"""Data shipped with piezopreload (see README.md in this folder)."""

from importlib import resources
from pathlib import Path

__all__ = ["shipped_data", "SHIPPED_COLUMNS"]

#: where time, input and output are in the shipped record (it has no header)
SHIPPED_COLUMNS = "time=1,input=3:voltage_V,output=2:displacement_um"


def shipped_data() -> Path:
    """The measured piezo hysteresis record shipped with the package (MIT licence)."""
    return Path(str(resources.files("piezopreload.data") / "hysteresis_v_150_1hz.csv"))
