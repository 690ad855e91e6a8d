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
from functools import cached_property
from typing import TYPE_CHECKING, Any

import control
import numpy as np

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.tuning import ActiveBound
from piezopreload.core.errors import InputError
from piezopreload.tuning.loopshape import BOUNDS, Bound
from piezopreload.tuning.lti import LinearPlant
from piezopreload.tuning.pidform import PIDController

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["AutotuneResult", "Margins", "SampledCheck", "StartRecord", "LOOPS", "sensitivity_peaks", "located_peaks",
           "located", "margins_of", "achieved"]

#: how far (relative) a bound may be exceeded (the autotuner's tolerance)
_TOLERANCE = 0.005
#: how far the refinement aims to hold every bound; a result over it says by how much (``over_by``)
REFINED_TO = 1e-4


def located(plant: LinearPlant, controller: PIDController, names: np.ndarray, omega: np.ndarray, idx: np.ndarray,
            sign: float = 1.0, steps: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The peaks of ``names[i]`` (``Ms``, ``Mt`` or ``Mks``: ``|S|``, ``|T|``, ``|KS|``) at the grid points
    ``idx[i]``, each located between its neighbours by bracketed parabolic interpolation in ``log w`` (the
    bracket's three points' parabola, its vertex kept at least a tenth of the larger side from the middle point so
    the bracket always shrinks: ``steps`` steps, all peaks at once): values and frequencies in the order given; a
    measured response's, and a grid end's, are the grid's own. ``sign`` multiplies the plant."""
    idx, names = np.asarray(idx, int), np.asarray(names, dtype=object)
    kinds = (names == Bound.MS, names == Bound.MT)  # |S|, |T|, else |KS|: compared once, not at every step

    def at(x: np.ndarray, which: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        w = np.exp(x)
        C = controller.response(w)
        L = C * sign * plant.response(w)
        num = np.where(which[0], 1.0, np.where(which[1], np.abs(L), np.abs(C)))
        return num / np.abs(1 + L)

    inner = (idx > 0) & (idx < omega.size - 1)
    if not (plant.rational and np.any(inner)):
        return at(np.log(omega[idx]), kinds), omega[idx].copy()
    k, which = idx[inner], (kinds[0][inner], kinds[1][inner])
    a, b, c = np.log(omega[k - 1]), np.log(omega[k]), np.log(omega[k + 1])
    # the grid's points and each bracket's ends in one evaluation
    both = (np.concatenate([kinds[0], which[0], which[0]]), np.concatenate([kinds[1], which[1], which[1]]))
    first = at(np.concatenate([np.log(omega[idx]), a, c]), both)
    values, where = first[:idx.size], omega[idx].copy()
    fa, fb, fc = first[idx.size:idx.size + k.size], values[inner], first[idx.size + k.size:]
    for _ in range(steps):
        ba, cb, bc, da, dc = b - a, c - b, b - c, fb - fa, fb - fc
        num = ba**2 * dc - bc**2 * da
        den = ba * dc - bc * da
        x = b - 0.5 * num / np.where(den != 0, den, 1.0)
        right = cb > ba  # the larger side; the vertex at least a tenth of it from b
        tenth = np.where(right, b + 0.1 * cb, b - 0.1 * ba)
        x = np.where((den == 0) | ~np.isfinite(x), np.where(right, b + 0.38 * cb, b - 0.38 * ba), x)
        x = np.clip(x, np.where(right, tenth, a), np.where(right, c, tenth))
        x = np.where(np.abs(x - b) < 0.1 * np.maximum(cb, ba), tenth, x)
        fx = at(x, which)
        up = fx > fb
        left = x < b
        # the new bracket: (a, x, b) or (x, b, c) when x < b; (b, x, c) or (a, b, x) when x > b
        na = np.where(left, np.where(up, a, x), np.where(up, b, a))
        nfa = np.where(left, np.where(up, fa, fx), np.where(up, fb, fa))
        nc = np.where(left, np.where(up, b, c), np.where(up, c, x))
        nfc = np.where(left, np.where(up, fb, fc), np.where(up, fc, fx))
        b, fb = np.where(up, x, b), np.where(up, fx, fb)
        a, fa, c, fc = na, nfa, nc, nfc
    values[inner], where[inner] = fb, np.exp(b)
    return values, where


def located_peaks(plant: LinearPlant, controller: PIDController, name: str, omega: np.ndarray, idx: np.ndarray,
                  sign: float = 1.0, steps: int = 8) -> list[tuple[float, float]]:
    """:func:`located` for one bound's peaks, ``(value, w)`` largest first."""
    values, where = located(plant, controller, np.full(np.size(idx), name, dtype=object), omega, idx, sign, steps)
    return sorted(zip(values.tolist(), where.tolist()), reverse=True)


def sensitivity_peaks(plant: LinearPlant, controller: PIDController, omega: np.ndarray,
                      names: tuple[str, ...] = BOUNDS, most: int = 3,
                      G: np.ndarray | None = None) -> dict[str, list[tuple[float, float]]]:
    """Per name (``Ms``: ``|S|``, ``Mt``: ``|T|``, ``Mks``: ``|KS|``) the ``most`` largest local peaks ``(value,
    frequency)`` on ``omega``, each located between its neighbours (:func:`located`, every name's at once), largest
    first. ``G``: the plant's response on ``omega`` where it is at hand."""
    G = plant.response(omega) if G is None else G
    C = controller.response(omega)
    picked = []
    for name in names:
        r = Bound(name).magnitude(C, G)
        top = np.zeros(r.size, bool)
        top[1:-1] = (r[1:-1] >= r[:-2]) & (r[1:-1] >= r[2:])
        top[int(np.argmax(r))] = True
        idx = np.flatnonzero(top)
        picked.append(idx[np.argsort(-r[idx])][:most])
    which = np.concatenate([np.full(i.size, n, dtype=object) for n, i in zip(names, picked)])
    values, where = located(plant, controller, which, omega, np.concatenate(picked), steps=10)
    return {name: sorted(zip(values[which == name].tolist(), where[which == name].tolist()), reverse=True)
            for name in names}


def achieved(plant: LinearPlant, controller: PIDController, omega: np.ndarray,
             G: np.ndarray | None = None) -> dict[str, tuple[float, float]]:
    """The largest ``|S|``, ``|T|``, ``|KS|`` and where (rad/s); ``G``: the plant's response on ``omega`` where it is
    at hand."""
    return {k: v[0] for k, v in sensitivity_peaks(plant, controller, omega, G=G).items()}


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


def margins_of(plant: LinearPlant, controller: PIDController, peaks: dict[str, tuple[float, float]] | None = None,
               resolved: tuple[np.ndarray, np.ndarray] | None = None) -> Margins:
    """:class:`Margins` of the loop; ``peaks`` (from :func:`achieved`) where already found, else on the Nyquist grid;
    ``resolved``: the loop on its resolved grid (:meth:`~piezopreload.tuning.lti.LinearPlant.resolved_loop`) where
    already computed."""
    omega, loop = resolved if resolved is not None else plant.resolved_loop(lambda w: controller.response(w))
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
    # |L| at each, by linear interpolation in the phase of log |L|; the gain margin from the largest below 1
    edge = np.floor(np.maximum(turns[k], turns[k + 1]))
    f = (edge - turns[k]) / (turns[k + 1] - turns[k])
    m = np.exp(np.log(mag[k]) + f * (np.log(mag[k + 1]) - np.log(mag[k])))
    if np.any(m < 1.0):
        gm = float(1.0 / np.max(m[m < 1.0]))
    return Margins(Ms=peaks[Bound.MS][0], Mt=peaks[Bound.MT][0], Mks=peaks[Bound.MKS][0],
                   Ms_rad_per_s=peaks[Bound.MS][1], Mt_rad_per_s=peaks[Bound.MT][1], Mks_rad_per_s=peaks[Bound.MKS][1],
                   gain_margin=gm,
                   phase_margin_deg=None if pm is None else float(np.degrees(pm)),
                   delay_margin_s=None if dm is None else float(dm), crossover_rad_per_s=wc)


@dataclass(frozen=True)
class StartRecord:
    """One start and what the local solver made of it: the gains reached (parallel form), the objective (``-ki``, or
    the scaled IAE), the worst bound's ``|X| / M - 1`` on the design grid, whether the loop is stable, the solver's
    status, iterations, time."""

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


#: the loops the bounds can hold on
LOOPS = ("continuous", "sampled")


@dataclass(frozen=True)
class SampledCheck:
    """The autotuned loop as it will run at a sample period (:meth:`AutotuneResult.discrete_check`).

    Parameters
    ----------
    sample_period_s : float
        The sample period, s: the controller step behind a zero-order hold.
    stable : bool
        Whether the sampled loop is stable.
    achieved : dict of str to float
        The largest ``|S|``, ``|T|``, ``|KS|`` reached (``Ms``, ``Mt``, ``Mks``).
    over_by : dict of str to float
        How far each bound set is exceeded, as a fraction of it (negative: met with room).
    tolerance : float
        The fraction a bound may be exceeded by.
    passed : bool
        Whether the loop is stable and every bound holds within the tolerance.
    bounds : dict of str to float
        The bounds set.
    """

    sample_period_s: float
    stable: bool
    achieved: dict[str, float]
    over_by: dict[str, float]
    tolerance: float
    passed: bool
    bounds: dict[str, float]

    def misses(self) -> str:
        """What the loop misses, in words: its instability or each bound over the tolerance, by how much.

        Returns
        -------
        str
            That the sampled loop is unstable, or each bound it exceeds beyond the tolerance, with the achieved peak and
            the share it is over by.
        """
        if not self.stable:
            return f"the loop as it will run at Ts {self.sample_period_s:g} s is unstable"
        over = [f"{k} {self.achieved[k]:.4g} against {self.bounds[k]:g} (over by {x:.1%})"
                for k, x in self.over_by.items() if x > self.tolerance]
        return (f"the loop as it will run at Ts {self.sample_period_s:g} s misses its bounds beyond the "
                f"{self.tolerance:.1%} tolerance: " + ", ".join(over))

    def to_dict(self) -> dict[str, Any]:
        """The check as ``autotune --json`` prints it.

        Returns
        -------
        dict
            ``sample_period_s`` (s), ``stable``, ``achieved`` (each peak), ``over_by`` (each bound's excess as a share),
            ``tolerance``, ``passed`` and ``bounds``.
        """
        return {"sample_period_s": self.sample_period_s, "stable": self.stable, "achieved": dict(self.achieved),
                "over_by": dict(self.over_by), "tolerance": self.tolerance, "passed": self.passed,
                "bounds": dict(self.bounds)}


@dataclass(frozen=True, eq=False)
class AutotuneResult:
    """The autotuner's result (see the module docstring); :func:`~piezopreload.tuning.autotune.autotune` makes it.

    ``grid_points`` is the design grid's size, ``check_points`` the check grid's (ten times as dense).
    ``bounds`` are the bounds the problem held: the user's (``user_bounds``) and the defaults the tuner set where
    the user set none (``defaults``: name -> ``{"value", "reason"}``, with the filter's floor ``Tf_min_s``);
    ``loop`` says which loop they hold on (``"continuous"``: the continuous controller on the plant; ``"sampled"``:
    the controller step at ``sample_period_s`` on the plant behind a zero-order hold); ``leans_on`` names, in
    sentences, each bound the user did not set that the result sits on.

    Parameters
    ----------
    controller_ : PIDController
        The tuned controller.
    plant : LinearPlant
        The plant as given.
    design_plant : LinearPlant
        The plant the bounds were held on (the sampled loop's, where ``loop`` is ``"sampled"``).
    form : {'PI', 'PID'}
        The controller's form.
    metric : {'IE', 'IAE'}
        What was optimised: the integral gain, or the IAE of a unit load step.
    bounds : dict
        The bounds the problem held (``Ms``, ``Mt``, ``Mks``; None: not bounded).
    margins : Margins
        The margins reached: the peaks of ``|S|``, ``|T|`` and ``|KS|``, gain, phase and delay margins.
    peaks : dict
        Each peak's name and its ``(frequency in rad/s, magnitude)``.
    stable : bool
        Whether the loop is stable.
    iae : float or None
        The IAE of a unit load step at the plant input (None: the metric is ``IE``, nothing simulated).
    iae_Ts : float or None
        The sample period that load step was simulated at (s).
    starts : tuple of StartRecord
        The starts of the local solver and what became of each.
    active_bounds : tuple of ActiveBound
        The gains on the ends of their range.
    grid_points, check_points : int
        The sizes of the design grid and of the check grid (ten times as dense).
    refinements : int
        The rounds of the winning start's solve in which the design grid was refined where a bound was exceeded.
    iterations : int
        The local solver's iterations, over all starts.
    seconds : float
        The wall-clock time it took (s).
    solver : str
        The local solver.
    loop : {'continuous', 'sampled'}
        Which loop the bounds hold on.
    sample_period_s : float or None
        The sample period the controller runs at (s).
    user_bounds : dict
        The bounds the user set.
    defaults : dict
        The bounds the tuner set where the user set none: name -> ``{"value", "reason"}``.
    leans_on : tuple of str
        Each bound the user did not set that the result sits on, in a sentence.
    u_range : (float, float) or None
        The actuator's range, the gain set's output range.
    load_step : object
        The simulated load step (None: not simulated).
    """

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
    solver: str = "sqp"
    loop: str = "continuous"
    sample_period_s: float | None = None
    user_bounds: dict[str, float | None] = field(default_factory=dict)
    defaults: dict[str, dict[str, Any]] = field(default_factory=dict)
    leans_on: tuple[str, ...] = ()
    u_range: tuple[float, float] | None = None
    load_step: Any = field(default=None, repr=False)

    # ---- the gains -------------------------------------------------------------------------------
    @property
    def kp(self) -> float:
        """Proportional gain of ``C = (kp + ki/s + kd s) F(s)``."""
        return self.controller_.parallel()[0]

    @property
    def ki(self) -> float:
        """The integral gain of the parallel form ``kp + ki/s + kd s`` (the filter on the whole controller)."""
        return self.controller_.parallel()[1]

    @property
    def kd(self) -> float:
        """The derivative gain of the parallel form ``kp + ki/s + kd s`` (the filter on the whole controller)."""
        return self.controller_.parallel()[2]

    @property
    def Tf(self) -> float:
        """The filter's time constant (s): ``F = 1/(Tf s + 1)`` (first order) or ``1/(1 + Tf s + (Tf s)^2/2)``."""
        return self.controller_.parallel()[3]

    @property
    def filter_order(self) -> int:
        """The controller's form: 0 a PI, 1 the derivative filtered, 2 a second-order filter on the whole controller."""
        return self.controller_.filter_order

    @property
    def ie(self) -> float:
        """The integrated error of a unit load step at the plant input, ``1/|ki|``."""
        return 1.0 / abs(self.ki)

    @property
    def gains(self) -> Any:
        """The ideal/ISA gains ``Kc, Ti, Td, Tf`` the controller step runs
        (:class:`~piezopreload.models.controller.PIDGains`, no output limit; a second-order filter's with
        ``filter_order`` 2, the measurement through it)."""
        return self.controller_.isa()

    @property
    def controller(self) -> control.TransferFunction:
        """The controller as a continuous python-control transfer function, its filter included (a sampled-loop
        design's: the continuous controller whose controller step at ``Ts`` was tuned)."""
        c = self.controller_
        return PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, None).transfer_function()

    @property
    def Ts(self) -> float | None:
        """The sample period the controller runs at (the ``Ts`` given, or a discrete plant's; None: none given)."""
        return self.sample_period_s

    @cached_property
    def load_response(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(t_s, y)``: the output's response to a unit load step at the plant input, simulated as the controller
        step runs it (None where the plant has no time-domain model); computed when first asked for."""
        return None if self.load_step is None else self.load_step()

    def discrete(self, Ts: float, method: str | None = None) -> control.TransferFunction:
        """The controller at sample period ``Ts``: by default as the controller step runs it (trapezoidal integral,
        backward-Euler filtered derivative; Tustin's map for a second-order filter); or by python-control's
        ``sample_system`` with ``method`` (``"tustin"``, ``"zoh"``, ...).

        Parameters
        ----------
        Ts : float
            The sample period, in s.
        method : str or None
            python-control's discretisation (``"tustin"``, ``"zoh"``, ...); None: as the controller step runs it.

        Returns
        -------
        control.TransferFunction
            The discrete controller, at sample period ``Ts``.

        Raises
        ------
        InputError
            Where ``Ts`` is not a finite number > 0.
        """
        if not (isinstance(Ts, int | float) and math.isfinite(Ts) and Ts > 0):
            raise InputError(f"Ts must be a finite number > 0, got {Ts!r}")
        c = self.controller_
        if method is None:
            return PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, float(Ts)).transfer_function()
        return control.sample_system(self.controller, Ts, method=method)

    # ---- what it is in words ----------------------------------------------------------------------
    def loop_text(self) -> str:
        """Which loop the bounds hold on, in words.

        Returns
        -------
        str
            The sampled loop at its period (the controller step, the plant behind a zero-order hold), or the continuous
            loop.
        """
        if self.loop == "sampled":
            return (f"the sampled loop at Ts {self.sample_period_s:g} s (the controller step, the plant behind a "
                    "zero-order hold)")
        return "the continuous loop (the continuous controller on the plant)"

    @property
    def over_by(self) -> dict[str, float]:
        """Each bound the result exceeds by more than the refinement's aim (:data:`REFINED_TO`, 0.01 %) on the check
        grid: name -> ``|X| / M - 1`` (the search accepts at most its tolerance, 0.5 %). Empty where every bound
        holds to the aim."""
        return {k: self.peaks[k][0] / v - 1.0 for k, v in self.bounds.items()
                if v is not None and self.peaks[k][0] > v * (1.0 + REFINED_TO)}

    def _bound_text(self) -> str:
        return ", ".join(f"{k} {self.peaks[k][0]:.3g} <= {v:g}" + (" (default)" if k in self.defaults else "")
                         for k, v in self.bounds.items() if v is not None)

    def __repr__(self) -> str:
        c = self.controller_
        kind = "PI" if c.filter_order == 0 or c.kd == 0 else f"PID (filter order {c.filter_order})"
        mg = self.margins
        runs = "" if self.sample_period_s is None else f", runs at Ts {self.sample_period_s:g} s"
        return (f"AutotuneResult({kind}, bounds on the {self.loop} loop{runs}: "
                f"kp {self.kp:.4g}, ki {self.ki:.4g}, kd {self.kd:.4g}, Tf {self.Tf:.4g} s; "
                + (f"IE {self.ie:.4g}" if self.iae is None else f"IAE {self.iae:.4g} (IE {self.ie:.4g})")
                + f"; {self._bound_text()}; GM {'inf' if mg.gain_margin is None else f'{mg.gain_margin:.4g}'}, "
                f"PM {_fmt(mg.phase_margin_deg, ' deg', 3)}, "
                f"delay margin {_fmt(mg.delay_margin_s, ' s')}; {'stable' if self.stable else 'UNSTABLE'}"
                + (f"; leans on {len(self.leans_on)} bound(s) you did not set" if self.leans_on else "")
                + "".join(f"; {k} over by {v:.3%}" for k, v in self.over_by.items())
                + f"; {len(self.starts)} starts, {self.refinements} refinements, {self.seconds * 1e3:.0f} ms)")

    def _repr_html_(self) -> str:
        rows = [("kp, ki, kd, Tf", f"{self.kp:.5g}, {self.ki:.5g}, {self.kd:.5g}, {self.Tf:.5g} s")]
        if self.kp > 0 and self.ki > 0:
            g = self.gains
            rows.append(("Kc, Ti, Td, Tf (ISA)", f"{g.Kc:.5g}, {g.Ti_s:.5g} s, {g.Td_s:.5g} s, {g.Tf_s:.5g} s"))
        mg = self.margins
        rows += [("metric", f"{self.metric}: IE {self.ie:.5g}" + ("" if self.iae is None else f", IAE {self.iae:.5g}")),
                 ("bounds hold on", self.loop_text()),
                 ("Ms, Mt, Mks reached", f"{mg.Ms:.4g}, {mg.Mt:.4g}, {mg.Mks:.4g}"),
                 ("bounds", ", ".join(f"{k} {v:g}" for k, v in self.bounds.items() if v is not None)),
                 ("defaults set", "; ".join(f"{k} {d['value']:.4g}: {d['reason']}" for k, d in self.defaults.items())
                  or "none"),
                 ("leans on bounds you did not set", "; ".join(self.leans_on) or "none"),
                 ("gain, phase, delay margin", f"{'inf' if mg.gain_margin is None else f'{mg.gain_margin:.4g}'}, "
                                               f"{_fmt(mg.phase_margin_deg, ' deg', 3)}, "
                                               f"{_fmt(mg.delay_margin_s, ' s')}"),
                 ("closed loop", "stable" if self.stable else "UNSTABLE"),
                 ("on a bound", "; ".join(b.sentence() for b in self.active_bounds) or "none"),
                 ("solve", f"{self.solver}, {len(self.starts)} starts, {self.iterations} iterations, "
                           f"{self.refinements} refinements, {self.seconds * 1e3:.0f} ms")]
        body = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                       for k, v in rows)
        return f"<table><caption>AutotuneResult ({html.escape(self.form)})</caption>{body}</table>"

    def to_dict(self) -> dict[str, Any]:
        """Everything as JSON-ready numbers (what ``piezopreload autotune --json`` prints).

        Returns
        -------
        dict
            The form, the loop, the gains (parallel, and ideal/ISA where kp and ki are positive), the bounds the user
            set and the defaults, what it leans on, the margins, the active bounds, the starts, the solver's counts and
            time, and the plant's delay, sample period and poles.
        """
        c = self.controller_
        out: dict[str, Any] = {
            "form": self.form, "filter_order": c.filter_order, "metric": self.metric, "loop": self.loop,
            "bounds_hold_on": self.loop_text(), "Ts_s": self.sample_period_s,
            "kp": self.kp, "ki": self.ki, "kd": self.kd, "Tf_s": self.Tf, "ie": self.ie, "iae": self.iae,
            "iae_Ts_s": self.iae_Ts, "bounds": {k: v for k, v in self.bounds.items() if v is not None},
            "user_bounds": {k: v for k, v in self.user_bounds.items() if v is not None},
            "defaults": {k: dict(v) for k, v in self.defaults.items()}, "leans_on": list(self.leans_on),
            "over_by": self.over_by,
            "u_range": None if self.u_range is None else list(self.u_range),
            "margins": self.margins.to_dict(), "stable": self.stable,
            "active_bounds": [b.to_dict() for b in self.active_bounds], "starts": [s.to_dict() for s in self.starts],
            "grid_points": self.grid_points, "check_points": self.check_points, "refinements": self.refinements,
            "iterations": self.iterations, "seconds": self.seconds, "solver": self.solver,
            "plant": {"source": self.plant.source, "delay_s": self.plant.delay_s, "dt_s": self.plant.dt,
                      "delay_samples": self.plant.delay_samples,
                      "unstable_poles": self.plant.unstable_poles, "integrators": self.plant.integrators},
        }
        if self.kp > 0 and self.ki > 0:
            g = self.gains
            out["gains"] = {"Kc": g.Kc, "Ti_s": g.Ti_s, "Td_s": g.Td_s, "Tf_s": g.Tf_s, "filter_order": g.filter_order}
        return out

    # ---- its picture ---------------------------------------------------------------------------------
    def plot(self) -> Figure:
        """The gang of four (``|S|``, ``|T|``, ``|PS|``, ``|CS|``) with the bounds, and the load step: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The gang of four's magnitudes with their bounds, and the response to a load step.
        """
        from piezopreload.tuning.autotune_plot import draw

        return draw(self)

    # ---- the gain set ----------------------------------------------------------------------------------
    def discrete_check(self, Ts: float) -> SampledCheck:
        """The loop as it will run at sample period ``Ts`` (the controller step, the plant behind a zero-order hold):
        stable?, the largest ``|S|``, ``|T|``, ``|KS|``, and whether every bound holds within the tolerance.

        Parameters
        ----------
        Ts : float
            The sample period, in s.

        Returns
        -------
        SampledCheck
            Whether the sampled loop is stable, its peaks of ``|S|``, ``|T|`` and ``|KS|``, each bound's excess and
            whether every bound holds within the tolerance.
        """
        c = self.controller_
        sampled = self.plant.sampled(Ts)
        ctrl = PIDController(c.kp, c.ki, c.kd, c.Tf, c.filter_order, float(Ts))
        omega, _ = sampled.resolved_loop(lambda w: ctrl.response(w))
        peaks = achieved(sampled, ctrl, omega)
        stable = sampled.closed_loop_stable(ctrl)
        over = {k: peaks[k][0] / v - 1.0 for k, v in self.bounds.items() if v is not None}
        met = stable and all(x <= _TOLERANCE for x in over.values())
        return SampledCheck(float(Ts), stable, {k: v[0] for k, v in peaks.items()}, over, _TOLERANCE, met,
                            {k: v for k, v in self.bounds.items() if v is not None})

    def to_gain_set(self, sample_period_s: float | None = None, *, u_min_V: float | None = None,
                    u_max_V: float | None = None, b: float = 1.0, name: str | None = None) -> GainSet:
        """The tuned gains as a gain set the exports write (ideal/ISA, output range ``u_min_V..u_max_V``, by default
        the actuator's range the tuning was given; setpoint weight ``b``) at ``sample_period_s`` (by default the
        ``Ts`` it was tuned with).

        It is ``validated`` when the loop as it will run at that period is stable and meets every bound within the
        tolerance (:meth:`discrete_check`) and the result leans on no bound the user did not set
        (:attr:`leans_on`), else a ``candidate``, which export refuses; its tuning record says which loop the bounds
        were tuned on, the defaults, what it leans on and why it has its status.

        Parameters
        ----------
        sample_period_s : float or None
            The controller's sample period, in s (None: the ``Ts`` it was tuned with).
        u_min_V, u_max_V : float or None
            The controller's output range, in V (None: the actuator's range the tuning was given).
        b : float
            The setpoint weight of the proportional part (no unit).
        name : str or None
            The gain set's preset name (None: none).

        Returns
        -------
        GainSet
            ``validated`` or ``candidate``, with its tuning record.

        Raises
        ------
        InputError
            Where no sample period or output range is known, or a sampled loop's gains are asked for at another period.
        """
        Ts = self.sample_period_s if sample_period_s is None else float(sample_period_s)
        if Ts is None:
            raise InputError("to_gain_set needs the controller's sample period (sample_period_s, or Ts when tuning): "
                             "the gain set runs as a discrete controller")
        tuned = self.sample_period_s
        if self.loop == "sampled" and tuned is not None and abs(Ts - tuned) > 1e-9 * tuned:
            raise InputError(f"the bounds were tuned on the sampled loop at Ts {tuned:g} s; its gain "
                             f"set runs at that period, not at {Ts:g} s")
        lo = u_min_V if u_min_V is not None else (None if self.u_range is None else self.u_range[0])
        hi = u_max_V if u_max_V is not None else (None if self.u_range is None else self.u_range[1])
        if lo is None or hi is None:
            raise InputError("to_gain_set needs the controller's output range: give u_min_V and u_max_V (or u_min and "
                             "u_max when tuning)")
        gains = self.controller_.isa(u_min_V=float(lo), u_max_V=float(hi), b=float(b))
        check = self.discrete_check(Ts)
        sampled = {"method": "the autotuned loop at its sample period: the controller step behind a zero-order "
                             "hold, its stability and its largest |S|, |T|, |KS| against the bounds",
                   **check.to_dict()}
        validated = check.passed and not self.leans_on
        reason = ("the loop as it will run is stable and meets every bound within the tolerance, all of them set by "
                  "the user" if validated else
                  "; ".join(([] if check.passed else [check.misses() + (
                      " (the bounds were tuned on the continuous loop: tune with loop='sampled' to hold them on the "
                      "loop as it runs)" if self.loop == "continuous" else "")])
                            + [f"leans on a bound the user did not set: {x}" for x in self.leans_on]))
        # its verdict is this check on the one linear plant it was tuned for (no Monte Carlo set: validation None)
        return GainSet(gains=gains, status="validated" if validated else "candidate", preset=name,
                       sample_period_s=Ts,
                       tuning={"autotune": self.to_dict(), "active_bounds": [x.to_dict() for x in self.active_bounds],
                               "bounds_hold_on": self.loop_text(), "defaults": self.to_dict()["defaults"],
                               "leans_on": list(self.leans_on), "status_reason": reason,
                               "sampled_loop_check": sampled},
                       inputs={"plant": self.plant.source})
