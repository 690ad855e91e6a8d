"""What the autotuner returns: the tuned controller, the margins it reaches, its picture, and its gain set.

:class:`AutotuneResult` holds the controller (:class:`~piezopreload.tuning.pidform.PIDController`),
the plant, the bounds asked for and the :class:`Margins` reached (the largest ``|S|``, ``|T|`` and
``|KS|`` by :func:`sensitivity_peaks`, gain and phase margins, the delay margin), the starts and
what became of each (:class:`StartRecord`), the gains on the ends of their range, and the solver's
numbers. It gives the gains in the issue's parallel form (``kp, ki, kd, Tf`` of ``C = (kp + ki/s +
kd s) F(s)``), in the ideal/ISA form the rest of the tool uses (:attr:`AutotuneResult.gains`), as
python-control transfer functions (:attr:`AutotuneResult.controller`, :meth:`AutotuneResult.discrete`),
draws itself (:meth:`AutotuneResult.plot`: the gang of four with the bounds, and the load step), and
becomes a gain set (:meth:`AutotuneResult.to_gain_set`) that ``piezopreload export`` writes for LabVIEW,
PLCs and C: ``validated`` when the loop as it will run (the controller step at the sample period,
the plant behind a zero-order hold) is stable and meets every bound within the tolerance.
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import control
import numpy as np
from scipy.optimize import minimize_scalar

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.tuning import ActiveBound
from piezopreload.core.errors import InputError
from piezopreload.tuning.lti import LinearPlant
from piezopreload.tuning.pidform import PIDController

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["AutotuneResult", "Margins", "StartRecord", "sensitivity_peaks", "margins_of", "achieved"]

_NAMES = {"Ms": "|S|", "Mt": "|T|", "Mks": "|KS|"}
#: how far (relative) a bound may be exceeded (the autotuner's tolerance)
_TOLERANCE = 0.005


def _magnitudes(name: str, C: np.ndarray, G: np.ndarray) -> np.ndarray:
    L = C * G
    num = {"Ms": np.ones_like(L.real), "Mt": np.abs(L), "Mks": np.abs(C)}[name]
    return num / np.abs(1 + L)


def sensitivity_peaks(plant: LinearPlant, controller: PIDController, omega: np.ndarray,
                      names: tuple[str, ...] = ("Ms", "Mt", "Mks"), above: dict[str, float] | None = None,
                      most: int = 8) -> dict[str, list[tuple[float, float]]]:
    """Per name (``Ms``: ``|S|``, ``Mt``: ``|T|``, ``Mks``: ``|KS|``) the local peaks ``(value, frequency)`` on
    ``omega``, each refined by a bounded scalar search between its neighbours (a rational plant; a measured
    response's are its data points), largest first: the ``most`` largest, or every one above ``above[name]``."""
    G, C = plant.response(omega), controller.response(omega)
    out = {}
    for name in names:
        r = _magnitudes(name, C, G)
        inner = np.flatnonzero((r[1:-1] >= r[:-2]) & (r[1:-1] >= r[2:])) + 1
        idx = sorted(set(inner.tolist()) | {int(np.argmax(r))}, key=lambda j: -r[j])
        idx = [j for j in idx if r[j] > above[name]] or idx[:1] if above is not None else idx[:most]
        out[name] = sorted((_refine(plant, controller, name, omega, i, float(r[i])) for i in idx), reverse=True)
    return out


def _refine(plant: LinearPlant, controller: PIDController, name: str, omega: np.ndarray, i: int,
            value: float) -> tuple[float, float]:
    if not plant.rational or i == 0 or i == omega.size - 1:
        return value, float(omega[i])

    def minus(log_w: float) -> float:
        w = np.array([np.exp(log_w)])
        return -float(_magnitudes(name, controller.response(w), plant.response(w))[0])

    res = minimize_scalar(minus, bounds=(np.log(omega[i - 1]), np.log(omega[i + 1])), method="bounded",
                          options={"xatol": 1e-8})
    return (-float(res.fun), float(np.exp(res.x))) if -res.fun > value else (value, float(omega[i]))


def achieved(plant: LinearPlant, controller: PIDController, omega: np.ndarray) -> dict[str, tuple[float, float]]:
    """The largest ``|S|``, ``|T|``, ``|KS|`` and where (rad/s)."""
    return {k: v[0] for k, v in sensitivity_peaks(plant, controller, omega).items()}


@dataclass(frozen=True)
class Margins:
    """What the loop reaches: the largest ``|S|``, ``|T|``, ``|KS|`` (``Mks`` in the controller's output per measured
    unit) and their frequencies (rad/s), the gain margin (None: infinite), the phase margin (deg) and the delay
    margin (s) at the gain crossover (rad/s; None where ``|L|`` does not cross 1)."""

    Ms: float
    Mt: float
    Mks: float
    Ms_rad_per_s: float
    Mt_rad_per_s: float
    Mks_rad_per_s: float
    gain_margin: float | None
    phase_margin_deg: float | None
    delay_margin_s: float | None
    crossover_rad_per_s: float | None

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def margins_of(plant: LinearPlant, controller: PIDController,
               peaks: dict[str, tuple[float, float]] | None = None) -> Margins:
    """:class:`Margins` of the loop; ``peaks`` (from :func:`achieved`) where already found, else on the Nyquist grid."""
    omega, loop = plant.resolved_loop(lambda w: controller.response(w))
    if peaks is None:
        peaks = achieved(plant, controller, omega)
    mag, phase = np.abs(loop), np.unwrap(np.angle(loop))
    cross = np.flatnonzero((mag[:-1] - 1.0) * (mag[1:] - 1.0) <= 0)
    pm = dm = wc = None
    for i in cross:  # the smallest phase margin over the gain crossovers
        f = (0.0 - np.log(mag[i])) / (np.log(mag[i + 1]) - np.log(mag[i])) if mag[i + 1] != mag[i] else 0.0
        w = float(np.exp(np.log(omega[i]) + f * (np.log(omega[i + 1]) - np.log(omega[i]))))
        ph = float(phase[i] + f * (phase[i + 1] - phase[i]))
        margin = (ph + 2 * np.pi) % (2 * np.pi) - np.pi  # 180 deg + the phase, wrapped into [-180, 180)
        if pm is None or margin < pm:
            pm, wc = margin, w
    if pm is not None and wc is not None:
        dm = pm / wc if pm > 0 else 0.0
    gm = None
    turns = (phase + np.pi) / (2 * np.pi)
    k = np.flatnonzero(np.diff(np.floor(turns)) != 0)  # phase crossings of -180 deg (mod 360)
    for i in k:  # |L| there, by linear interpolation in the phase of log |L|
        edge = np.floor(max(turns[i], turns[i + 1]))
        f = (edge - turns[i]) / (turns[i + 1] - turns[i])
        m = float(np.exp(np.log(mag[i]) + f * (np.log(mag[i + 1]) - np.log(mag[i]))))
        if m < 1.0 and (gm is None or 1.0 / m < gm):
            gm = 1.0 / m
    return Margins(Ms=peaks["Ms"][0], Mt=peaks["Mt"][0], Mks=peaks["Mks"][0], Ms_rad_per_s=peaks["Ms"][1],
                   Mt_rad_per_s=peaks["Mt"][1], Mks_rad_per_s=peaks["Mks"][1], gain_margin=gm,
                   phase_margin_deg=None if pm is None else float(np.degrees(pm)),
                   delay_margin_s=None if dm is None else float(dm), crossover_rad_per_s=wc)


@dataclass(frozen=True)
class StartRecord:
    """One start and what IPOPT (or SLSQP) made of it: the gains reached (parallel form), the objective, the worst
    bound's ``|X| / M - 1`` on the design grid, whether the loop is stable, the solver's status, iterations, time."""

    name: str
    kp: float
    ki: float
    kd: float
    Tf: float
    objective: float
    violation: float
    stable: bool
    status: str
    iterations: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _fmt(x: float | None, unit: str = "", digits: int = 4) -> str:
    return "none" if x is None else f"{x:.{digits}g}{unit}"


@dataclass(frozen=True, eq=False)
class AutotuneResult:
    """The autotuner's result (see the module docstring); :func:`~piezopreload.tuning.autotune.autotune` makes it."""

    controller_: PIDController
    plant: LinearPlant
    design_plant: LinearPlant
    form: str
    metric: str
    bounds: dict[str, float | None]
    margins: Margins
    peaks: dict[str, tuple[float, float]]
    stable: bool
    iae: float | None
    iae_Ts: float | None
    starts: tuple[StartRecord, ...]
    active_bounds: tuple[ActiveBound, ...]
    grid_points: int
    check_points: int
    refinements: int
    iterations: int
    seconds: float
    solver: str = "ipopt"
    load_response: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    # ---- the gains -------------------------------------------------------------------------------
    @property
    def kp(self) -> float:
        """Proportional gain of ``C = (kp + ki/s + kd s) F(s)``."""
        return self.controller_.parallel()[0]

    @property
    def ki(self) -> float:
        return self.controller_.parallel()[1]

    @property
    def kd(self) -> float:
        return self.controller_.parallel()[2]

    @property
    def Tf(self) -> float:
        """The filter's time constant (s): ``F = 1/(Tf s + 1)`` (first order) or ``1/(1 + Tf s + (Tf s)^2/2)``."""
        return self.controller_.parallel()[3]

    @property
    def filter_order(self) -> int:
        return self.controller_.filter_order

    @property
    def ie(self) -> float:
        """The integrated error of a unit load step at the plant input, ``1/|ki|``."""
        return 1.0 / abs(self.ki)

    @property
    def gains(self) -> Any:
        """The ideal/ISA gains ``Kc, Ti, Td, Tf`` the controller step runs
        (:class:`~piezopreload.models.controller.PIDGains`, no output limit); a second-order filter has none (an
        :class:`InputError` says so)."""
        return self.controller_.isa()

    @property
    def controller(self) -> control.TransferFunction:
        """The controller as a continuous python-control transfer function, its filter included (a discrete
        design's: the continuous controller whose discretisation at ``Ts`` was tuned)."""
        c = self.controller_
        return PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, None).transfer_function()

    @property
    def Ts(self) -> float | None:
        """The controller's sample period where it was tuned discrete (None: continuous)."""
        return self.controller_.dt

    def discrete(self, Ts: float, method: str | None = None) -> control.TransferFunction:
        """The controller at sample period ``Ts``: by default as the controller step runs it (trapezoidal integral,
        backward-Euler filtered derivative; Tustin's map for a second-order filter); or by python-control's
        ``sample_system`` with ``method`` (``"tustin"``, ``"zoh"``, ...)."""
        if not (isinstance(Ts, int | float) and math.isfinite(Ts) and Ts > 0):
            raise InputError(f"Ts must be a finite number > 0, got {Ts!r}")
        c = self.controller_
        if method is None:
            return PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, float(Ts)).transfer_function()
        return control.sample_system(self.controller, Ts, method=method)

    # ---- what it is in words ----------------------------------------------------------------------
    def _bound_text(self) -> str:
        return ", ".join(f"{k} {self.peaks[k][0]:.3g} <= {v:g}" for k, v in self.bounds.items() if v is not None)

    def __repr__(self) -> str:
        c = self.controller_
        kind = "PI" if c.filter_order == 0 or c.kd == 0 else f"PID (filter order {c.filter_order})"
        mg = self.margins
        return (f"AutotuneResult({kind}{'' if c.dt is None else f' at Ts {c.dt:g} s'}: "
                f"kp {self.kp:.4g}, ki {self.ki:.4g}, kd {self.kd:.4g}, Tf {self.Tf:.4g} s; "
                + (f"IE {self.ie:.4g}" if self.iae is None else f"IAE {self.iae:.4g} (IE {self.ie:.4g})")
                + f"; {self._bound_text()}; GM {'inf' if mg.gain_margin is None else f'{mg.gain_margin:.4g}'}, "
                f"PM {_fmt(mg.phase_margin_deg, ' deg', 3)}, "
                f"delay margin {_fmt(mg.delay_margin_s, ' s')}; {'stable' if self.stable else 'UNSTABLE'}; "
                f"{len(self.starts)} starts, {self.refinements} refinements, {self.seconds:.2f} s)")

    def _repr_html_(self) -> str:
        rows = [("kp, ki, kd, Tf", f"{self.kp:.5g}, {self.ki:.5g}, {self.kd:.5g}, {self.Tf:.5g} s")]
        if self.controller_.filter_order < 2:
            g = self.gains
            rows.append(("Kc, Ti, Td, Tf (ISA)", f"{g.Kc:.5g}, {g.Ti_s:.5g} s, {g.Td_s:.5g} s, {g.Tf_s:.5g} s"))
        mg = self.margins
        rows += [("metric", f"{self.metric}: IE {self.ie:.5g}" + ("" if self.iae is None else f", IAE {self.iae:.5g}")),
                 ("Ms, Mt, Mks reached", f"{mg.Ms:.4g}, {mg.Mt:.4g}, {mg.Mks:.4g}"),
                 ("bounds", ", ".join(f"{k} {v:g}" for k, v in self.bounds.items() if v is not None)),
                 ("gain, phase, delay margin", f"{'inf' if mg.gain_margin is None else f'{mg.gain_margin:.4g}'}, "
                                               f"{_fmt(mg.phase_margin_deg, ' deg', 3)}, "
                                               f"{_fmt(mg.delay_margin_s, ' s')}"),
                 ("closed loop", "stable" if self.stable else "UNSTABLE"),
                 ("on a bound", "; ".join(b.sentence() for b in self.active_bounds) or "none"),
                 ("solve", f"{self.solver}, {len(self.starts)} starts, {self.iterations} iterations, "
                           f"{self.refinements} refinements, {self.seconds:.2f} s")]
        body = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                       for k, v in rows)
        return f"<table><caption>AutotuneResult ({html.escape(self.form)})</caption>{body}</table>"

    def to_dict(self) -> dict[str, Any]:
        """Everything as JSON-ready numbers (what ``piezopreload autotune --json`` prints)."""
        c = self.controller_
        out: dict[str, Any] = {
            "form": self.form, "filter_order": c.filter_order, "metric": self.metric, "Ts_s": c.dt,
            "kp": self.kp, "ki": self.ki, "kd": self.kd, "Tf_s": self.Tf, "ie": self.ie, "iae": self.iae,
            "iae_Ts_s": self.iae_Ts, "bounds": {k: v for k, v in self.bounds.items() if v is not None},
            "margins": self.margins.to_dict(), "stable": self.stable,
            "active_bounds": [b.to_dict() for b in self.active_bounds], "starts": [s.to_dict() for s in self.starts],
            "grid_points": self.grid_points, "check_points": self.check_points, "refinements": self.refinements,
            "iterations": self.iterations, "seconds": self.seconds, "solver": self.solver,
            "plant": {"source": self.plant.source, "delay_s": self.plant.delay_s, "dt_s": self.plant.dt,
                      "unstable_poles": self.plant.unstable_poles, "integrators": self.plant.integrators},
        }
        if c.filter_order < 2:
            g = self.gains
            out["gains"] = {"Kc": g.Kc, "Ti_s": g.Ti_s, "Td_s": g.Td_s, "Tf_s": g.Tf_s}
        return out

    # ---- its picture ---------------------------------------------------------------------------------
    def plot(self) -> Figure:
        """The gang of four (``|S|``, ``|T|``, ``|PS|``, ``|CS|``) with the bounds, and the load step: a Figure."""
        from piezopreload.tuning.autotune_plot import draw

        return draw(self)

    # ---- the gain set ----------------------------------------------------------------------------------
    def discrete_check(self, Ts: float) -> dict[str, Any]:
        """The loop as it will run at sample period ``Ts`` (the controller step, the plant behind a zero-order hold):
        stable?, the largest ``|S|``, ``|T|``, ``|KS|``, and whether every bound holds within the tolerance."""
        c = self.controller_
        sampled = self.plant.sampled(Ts)
        ctrl = PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, float(Ts))
        omega, _ = sampled.resolved_loop(lambda w: ctrl.response(w))
        peaks = achieved(sampled, ctrl, omega)
        stable = sampled.closed_loop_stable(ctrl)
        over = {k: peaks[k][0] / v - 1.0 for k, v in self.bounds.items() if v is not None}
        met = stable and all(x <= _TOLERANCE for x in over.values())
        return {"sample_period_s": float(Ts), "stable": stable, "achieved": {k: v[0] for k, v in peaks.items()},
                "over_by": over, "tolerance": _TOLERANCE, "passed": met}

    def to_gain_set(self, sample_period_s: float | None = None, *, u_min_V: float, u_max_V: float, b: float = 1.0,
                    name: str | None = None) -> GainSet:
        """The tuned gains as a gain set the exports write (ideal/ISA, output range ``u_min_V..u_max_V``, setpoint
        weight ``b``) at ``sample_period_s`` (a discrete design's by default). It is ``validated`` when the loop
        as it will run at that period is stable and meets every bound within the tolerance
        (:meth:`discrete_check`), else a ``candidate``, which export refuses; its validation record says which."""
        Ts = self.Ts if sample_period_s is None else float(sample_period_s)
        if Ts is None:
            raise InputError("to_gain_set needs the controller's sample period (sample_period_s): the gain set runs "
                             "as a discrete controller")
        if self.Ts is not None and abs(Ts - self.Ts) > 1e-9 * self.Ts:
            raise InputError(f"the controller was tuned discrete at Ts {self.Ts:g} s; "
                             f"its gain set runs at that period, not at {Ts:g} s")
        gains = self.controller_.isa(u_min_V=float(u_min_V), u_max_V=float(u_max_V), b=float(b))
        check = self.discrete_check(Ts)
        sampled = {"method": "the autotuned loop at its sample period: the controller step behind a zero-order "
                             "hold, its stability and its largest |S|, |T|, |KS| against the bounds",
                   **check, "bounds": {k: v for k, v in self.bounds.items() if v is not None}}
        # its verdict is this check on the one linear plant it was tuned for (no Monte Carlo set: validation None)
        return GainSet(gains=gains, status="validated" if check["passed"] else "candidate", preset=name,
                       sample_period_s=Ts,
                       tuning={"autotune": self.to_dict(), "active_bounds": [x.to_dict() for x in self.active_bounds],
                               "sampled_loop_check": sampled},
                       inputs={"plant": self.plant.source})
