"""How a quantity is printed: one rule per kind of quantity, for the report, the console and their messages alike.

A figure carries the precision its source justifies and no more. Each unit names a kind of quantity and its
resolution (:data:`RESOLUTION`), the finest step worth printing: the force sensors' noise (1 N per sample on
the machine axis, 0.25 N on the paper's rig) leaves a force resolved to 0.1 N at best, however many samples an
RMS averages; the nut's Hertz model and the thermal model hold a length to a tenth of a micrometre at best
(their tolerance is several per cent of figures of 1-50 um); a time is resolved by the control loop's
millisecond sample. :func:`number` rounds to three significant digits and never finer than the unit's
resolution; a figure smaller than half the resolution prints as ``< 0.1`` (nothing finer is known of it).
A unit not in the table (a gain, a ratio) keeps its significant digits only.

>>> number(0.00211, "um"), number(0.0284, "N"), number(0.416, "N"), number(1704.4, "N")
('< 0.1', '< 0.1', '0.4', '1,704')
>>> quantity(0.0296, "%"), quantity(40.83, "%"), quantity(0.3218, "s"), quantity(1126.2, "N/um")
('0.03 %', '40.8 %', '0.322 s', '1,126 N/um')
>>> number(999.96, "N"), number(13236.0, "N"), number(0.00096, "s"), number(5.0, "um")
('1,000', '13,236', '0.001', '5')
>>> number(0.0108, "V/N", digits=4), number(-0.31, "N"), number(0.0, "um")
('0.0108', '-0.3', '0')
"""

from __future__ import annotations

import math

__all__ = ["RESOLUTION", "number", "quantity"]

#: the finest step worth printing, by unit (the quantity's kind); why each is in the module's text
RESOLUTION: dict[str, float] = {
    "N": 0.1,  # force: the sensors' noise, 0.25-1 N a sample
    "kN": 0.0001,
    "um": 0.1,  # length at the table: the nut's Hertz model and the thermal model, a few % of 1-50 um
    "mm": 0.001,
    "N/um": 1.0,  # rigidity: the Hertz model's tolerance, a few % of hundreds of N/um
    "s": 0.001,  # time: the control loop's 1 ms sample
    "ms": 1.0,
    "V": 0.1,  # command: the amplifier's resolution and noise
    "W": 0.1,
    "K": 0.1,  # temperature rise: the thermal model's tolerance
    "%": 0.01,  # a share: the force's 0.1 N over a range of about a thousand newtons
    "N m": 0.001,
    "Hz": 0.1,
    "MPa": 1.0,
    "h": 1.0,
    "deg": 0.1,
    "°": 0.1,
}


def number(x: float, unit: str = "", digits: int = 3) -> str:
    """``x`` as printed for its ``unit``: ``digits`` significant digits, never finer than the unit's resolution,
    thousands separated (1,704).

    Parameters
    ----------
    x : float
        The value, in ``unit``.
    unit : str
        Its unit, which names its kind (a key of :data:`RESOLUTION`; another unit keeps ``digits`` alone).
    digits : int
        The significant digits at most.

    Returns
    -------
    str
        The number without its unit; ``< r`` where it is nonzero and smaller than half the resolution ``r``.

    Raises
    ------
    ValueError
        Where ``x`` is None or not finite: a missing figure is left out with its reason, never printed as a dash.
    """
    if x is None or not math.isfinite(float(x)):
        raise ValueError(f"number: {x!r} cannot be printed; leave the figure out and say why")
    x = float(x)
    if x == 0.0:
        return "0"
    step = RESOLUTION.get(unit)
    if step is not None and abs(x) < step / 2:
        return f"< {_plain(step)}"
    exponent = math.floor(math.log10(abs(x)))
    decimals = digits - 1 - exponent  # the significant digits' last place
    if round(x, decimals) != 0.0 and math.floor(math.log10(abs(round(x, decimals)))) > exponent:
        decimals -= 1  # 999.6 to three digits is 1,000
    decimals = max(decimals, 0)  # a whole number keeps its digits (13,236, not 13,200)
    if step is not None:
        decimals = min(decimals, max(-math.floor(math.log10(step) + 1e-9), 0))
    rounded = round(x, decimals)
    text = f"{rounded:,.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text  # as %g: 5 um, not 5.0 um


def _plain(step: float) -> str:
    return f"{step:.{max(-math.floor(math.log10(step) + 1e-9), 0)}f}"


def quantity(x: float, unit: str, digits: int = 3) -> str:
    """``x`` with its unit, by :func:`number`'s rule (``1,126 N/um``, ``0.322 s``, ``40.8 %``)."""
    return f"{number(x, unit, digits)} {unit}".rstrip()
