"""The autotuner's picture: the gang of four with the bounds, and the load step (a matplotlib
Figure, no pyplot state)."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from piezopreload.tuning.pidform import PIDController

__all__ = ["draw"]


def draw(result: Any) -> Figure:
    """``|S|``, ``|T|``, ``|PS|`` and ``|CS|`` over frequency with ``Ms``, ``Mt``, ``Mks`` as dashed lines (left),
    the output's response to a unit load step at the plant input (right; absent for a measured response)."""
    plant = result.design_plant
    c: PIDController = result.controller_
    omega, loop = plant.resolved_loop(lambda w: c.response(w))
    G, C = plant.response(omega), c.response(omega)
    S = 1.0 / (1.0 + loop)
    curves = {"|S|": (np.abs(S), result.bounds.get("Ms")), "|T|": (np.abs(loop * S), result.bounds.get("Mt")),
              "|PS|": (np.abs(G * S), None), "|CS|": (np.abs(C * S), result.bounds.get("Mks"))}
    fig = Figure(figsize=(9.0, 5.6), layout="constrained")
    grid = fig.add_gridspec(2, 3)
    axes = [fig.add_subplot(grid[i // 2, i % 2]) for i in range(4)]
    for ax, (label, (mag, bound)) in zip(axes, curves.items()):
        ax.loglog(omega, mag, color="C0", lw=1.2)
        if bound is not None:
            ax.axhline(bound, color="C3", ls="--", lw=1.0, label=f"bound {bound:g}")
            ax.legend(loc="lower center", fontsize=7)
        ax.set_title(label, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[2:]:
        ax.set_xlabel("frequency (rad/s)")
    step = fig.add_subplot(grid[:, 2])
    if result.load_response is None:
        step.text(0.5, 0.5, "no time-domain model:\na measured frequency response", ha="center", va="center",
                  transform=step.transAxes, fontsize=9)
        step.set_axis_off()
    else:
        t, y = result.load_response
        step.plot(t, y, color="C0", lw=1.2)
        step.axhline(0.0, color="0.5", lw=0.6)
        step.set_xlabel("time (s)")
        step.set_title(f"unit load step at the plant input\nIE {result.ie:.3g}"
                       + ("" if result.iae is None else f", IAE {result.iae:.3g}"), fontsize=9)
        step.grid(True, alpha=0.3)
    mg = result.margins
    fig.suptitle(f"{result.form}: kp {result.kp:.3g}, ki {result.ki:.3g}, kd {result.kd:.3g}, Tf {result.Tf:.3g} s; "
                 f"Ms {mg.Ms:.3g}, Mt {mg.Mt:.3g}, Mks {mg.Mks:.3g}", fontsize=10)
    return fig
