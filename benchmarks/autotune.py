"""The autotuner on the plants practice brings, against an independent dense multi-start reference and SLSQP.

The batch (each plant's source named; where the source gives the model's form and the parameters are
chosen here, the table says so):

* Åström and Hägglund's 31 processes ("Benchmark systems for PID control", IFAC PID'00, 2000; the same
  families in Åström and Hägglund 2004, J. Process Control 14), at a subset of each family's
  parameters: P1 ``e^{-s}/(1 + sT)`` and P2 ``e^{-s}/(1 + sT)^2`` (T 0.1 to 10, lag- to
  delay-dominated); P3 ``1/(s + 1)^n`` (n = 3, 4, 8); P4 ``1/((1 + s)(1 + as)(1 + a^2 s)(1 + a^3 s))``;
  P5 ``(1 - as)/(s + 1)^3`` (non-minimum phase); P6 ``e^{-sL}/(s(1 + sT))``, T + L = 1 (integrating);
  P7 ``w0^2/((s + 1)(s^2 + 0.2 w0 s + w0^2))`` (oscillatory, zeta 0.1);
* the commercial peer's own test plants on its grid ``2 pi logspace(-2, 2, 1000)`` (:func:`peer_plants`): the
  near-integrating ``11.2/((s + 1e-5)(s + 0.12))`` (Ms = Mt = 1.2, Mks = 100) and the two-inertia plant (unit
  inertias, shaft 100, dampings 1; Ms 1.3, Mt 1.5, Mks 300) measured on the motor and on the load, the reference
  there a PID with the peer's second-order filter on the whole controller, ``(kp + ki/s + kd s) / (1 + Tf s +
  (Tf s)^2 / 2)``; every bound checked on the peer's grid and on one ten times denser;
* 11 sampled loops with delays of 1 to 10,000 samples at sample periods 1e-4 to 0.1 s (:func:`sampled`), the
  reference on the exact zero-order-hold loop (``control.c2d`` times ``z^-N``), the stability of a loop whose
  delay line is longer than 50 samples by the Nyquist criterion on a grid of eight points a sample of delay;
* 17 more, of the classes the batch above lacks (:func:`practice`):

  ==================  ==============================================================  =================================
  plant               model                                                           source
  ==================  ==============================================================  =================================
  near-int 1e3        ``1/((1000 s + 1)(s + 1))`` (poles three decades apart)         Skogestad 2003, J. Process
                                                                                      Control 13 (SIMC): lag-dominant
                                                                                      processes read as integrating
  near-int 1e4 L      ``e^{-0.1 s}/((10^4 s + 1)(s + 1))`` (four decades)             the same class, with a delay
  near-int 1e4 Ts     the same on the sampled loop at Ts = 0.01 s                     the same
  two-mass speed      motor speed from torque, compliant shaft, load: an              Ellis, Control System Design
                      integrator, an anti-resonance at 0.7 of a resonance at          Guide (the resonant load);
                      300 rad/s, zeta 0.02, with a 1 ms delay                         parameters chosen here
  two-mass position   load position from torque through the shaft: a double           the same
                      integrator and the resonance at 150 rad/s, zeta 0.01, PI
                      on the speed loop's output left out: a PID with |KS| bound
  screw axial mode    ``w^2/((s/p + 1)(s^2 + 2 zeta w s + w^2))``, 200 Hz, zeta 0.01  the ball-screw feed drive's
                      behind an amplifier lag (p = 2 pi 500 rad/s) and a 0.2 ms       first axial mode (this tool's
                      delay                                                           paper, eq. (1)); values chosen
  unstable 1          ``e^{-0.1 s}/(s - 1)``                                          De Paor and O'Malley 1989, Int.
                                                                                      J. Control 49: unstable first
                                                                                      order with delay
  unstable 2          ``e^{-0.939 s}/((5 s - 1)(2.07 s + 1))``                        Huang and Chen 1997, J. Chem.
                                                                                      Eng. Japan 30 (second-order
                                                                                      unstable with delay)
  delay-dominant      ``e^{-5 s}/((s + 1)(0.5 s + 1))``                               Åström and Hägglund 2006,
                                                                                      Advanced PID Control: the
                                                                                      delay-dominated class
  high order          ``(-0.3 s + 1)(0.08 s + 1)/((2 s + 1)(s + 1)(0.4 s + 1)         Skogestad 2003 (the half rule's
                      (0.2 s + 1)(0.05 s + 1)^3)``                                    example)
  nmp zero            ``(-2 s + 1)/((s + 1)(0.5 s + 1)^2)``                           Åström and Hägglund 2006: the
                                                                                      inverse-response class (a RHP
                                                                                      zero at 0.5 rad/s)
  integrating lag     ``e^{-0.5 s}/(s (2 s + 1))``                                    Skogestad 2003 (integrating
                                                                                      with lag and delay)
  oscillatory 0.02    ``4/((s + 1)(s^2 + 0.08 s + 4))`` (zeta 0.02)                   Åström and Hägglund 2000, P7's
                                                                                      family, lighter damping
  frd fotd noise      AH P2 T = 1 measured: 250 points a decade over five decades,    a swept-sine measurement
                      1 % complex noise (seeded)                                      (noise model chosen here)
  frd resonant noise  "screw axial mode" measured the same way                        the same
  lag3 delay Ts       ``e^{-0.2 s}/(s + 1)^3`` on the sampled loop at Ts = 0.01 s     the issue's example
  PI unstable Ts      "unstable 1" on the sampled loop at Ts = 0.02 s, a PI           De Paor and O'Malley 1989
  ==================  ==============================================================  =================================

The problem: a PID (first-order filter on the derivative; "PI" where named) for the largest ki under
``|S| <= Ms``, ``|T| <= Mt`` and ``|KS| <= Mks`` with a stable loop: Ms = Mt = 1.4 and Mks = 5 (a
unit static gain's high-frequency controller gain of five) for the 31, per plant below for the others
(an unstable plant's ``|T|`` is at least ``e^{pL}`` for any stabilising controller, so Mt is looser there).

Per plant, in the same run:

* the reference ki: an independent dense multi-start, written here without the package's code: the
  plant's response from python-control (``control.tf`` evaluated on the frequency axis, the delay as
  ``e^{-j w L}``; a sampled loop: ``control.c2d(..., "zoh")`` and whole-sample delays; measured data as
  given), the controller's from its formula, 100 points a decade (and a cluster at each lightly damped
  pole or zero), a Latin hypercube of 400 gains in a box from the plant's poles, the 48 best of them
  (stable by the Nyquist criterion, by least violation or largest ki) each solved by scipy's SLSQP with
  analytic gradients in log-gains, the best that meets every bound on its grid with a stable loop;
* the autotuner (``solver="sqp"``) three times, and SLSQP on the same problem (``solver="slsqp"``: the
  same pipeline with scipy's SLSQP as the local solver, exact first derivatives) three times; the
  per-plant time is the median of three;
* every bound of ours checked on a grid ten times denser than the tuner's (250 points a decade over
  three decades beyond the plant's poles and zeros each side, 2,000 points across each lightly damped
  pair; a measured plant: every data point, 250 a decade) with python-control's response and the
  controller's formula; the loop's stability from python-control's closed-loop poles in state space (a
  12th-order Padé for a delay; a measured plant: the model it was measured from).

Figures (the last line of output, one JSON object): ``ki_over_reference_min`` (target >= 0.99),
``bound_violation_max`` (``max |X| / M - 1`` over every plant and bound; target <= 0.005), ``all_stable``,
``sampled_worst_s`` (the slowest of the sampled long-delay loops; target <= 0.5), ``peer_ki_over_reference_min`` and
``sampled_ki_over_reference_min`` (those groups' least ratio),
``median_s_per_plant`` (target <= 0.05), ``worst_s_per_plant`` (<= 0.5), ``autotune_vs_slsqp_time_ratio``
(our total time over SLSQP's; aim <= 0.5) and ``autotune_vs_slsqp_time_ratio_median`` (the median of the plants'
own ratios: the sum leans on SLSQP's slowest plants), ``median_cpu_s_per_plant``, ``worst_cpu_s_per_plant`` (this
process's CPU seconds: the machine's other work inflates wall time, not these), ``first_call_s`` (the first
plant's first call, which builds the compiled functions), ``loadavg_1min`` (the machine's load: other work makes
times noisy; the ratio is measured in the same run). ``--only NAME`` runs the plants whose name contains NAME;
``--write-docs`` writes the figures' table into docs/autotune.md.
"""

from __future__ import annotations

import os

# BLAS threads only cost on problems this small: their spinning takes the other core from the tuner on a 2-core
# machine (docs/benchmarks.md gives both figures). One thread unless OPENBLAS_NUM_THREADS or --blas-threads=N says
# otherwise, set before numpy loads (this module is run, not imported: the setting is the benchmark's own).
if __name__ == "__main__":
    import sys

    _given = [a.split("=", 1)[1] for a in sys.argv if a.startswith("--blas-threads=")]
    if _given:
        os.environ["OPENBLAS_NUM_THREADS"] = _given[-1]
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import statistics
import time
from dataclasses import dataclass, field, replace
from typing import Any

import control
import numpy as np
from scipy.optimize import minimize
from scipy.stats import qmc

from piezopreload.tuning.autotune import autotune

PER_DECADE_REF = 100
CHECK_PER_DECADE = 250  # ten times the tuner's 25
REF_CANDIDATES, REF_STARTS = 4000, 40
REPEATS = 3


@dataclass
class Case:
    """A plant and its problem: the rational part (or measured data with the model it came from), the delay, the
    bounds, the form, the sample period of a sampled-loop problem, the source."""

    name: str
    G: Any
    delay: float
    Ms: float = 1.4
    Mt: float | None = 1.4
    Mks: float | None = 5.0
    form: str = "PID"
    Ts: float | None = None
    source: str = ""
    model: Any = None  # a measured plant's noise-free model (its stability check)
    extra: dict[str, Any] = field(default_factory=dict)
    w: Any = None  # a grid given (the peer's): ours and the reference tune on it, the check is ten times denser
    ref_form: str | None = None  # the reference's own form where it differs ("PID2": the peer's second-order filter)
    sampled_set: bool = False  # one of the sampled-loop cases with long delays (sampled_worst_s)

    @property
    def measured(self) -> bool:
        return isinstance(self.G, control.FrequencyResponseData)


def astrom_hagglund() -> list[Case]:
    src = "Astrom and Hagglund 2000"
    out = []
    for T in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0):
        out.append(Case(f"P1 T={T:g}", control.tf([1.0], [T, 1.0]), 1.0, source=src))
    for T in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0):
        out.append(Case(f"P2 T={T:g}", control.tf([1.0], np.polymul([T, 1.0], [T, 1.0])), 1.0, source=src))
    for n in (3, 4, 8):
        out.append(Case(f"P3 n={n}", control.tf([1.0], np.poly(-np.ones(n))), 0.0, source=src))
    for a in (0.2, 0.5):
        den = np.polymul(np.polymul([1.0, 1.0], [a, 1.0]), np.polymul([a**2, 1.0], [a**3, 1.0]))
        out.append(Case(f"P4 a={a:g}", control.tf([1.0], den), 0.0, source=src))
    for a in (0.1, 0.5, 1.0, 2.0):
        out.append(Case(f"P5 a={a:g}", control.tf([-a, 1.0], np.poly(-np.ones(3))), 0.0, source=src))
    for L in (0.1, 0.3, 0.5, 0.9):
        out.append(Case(f"P6 L={L:g}", control.tf([1.0], [1.0 - L, 1.0, 0.0]), L, source=src))
    for w0 in (1.0, 2.0, 5.0, 10.0):
        out.append(Case(f"P7 w0={w0:g}", control.tf([w0**2], np.polymul([1.0, 1.0], [1.0, 0.2 * w0, w0**2])), 0.0,
                        source=src))
    return out


def _two_mass_speed() -> control.TransferFunction:
    """Motor speed over motor torque, motor and load on a compliant shaft (inertias 1e-3 kg m^2 each, shaft
    45 N m/rad, damping for zeta 0.02): ``(J_L s^2 + c s + k) / (s (J_M J_L s^2 + (J_M + J_L)(c s + k)))``, an
    anti-resonance at 212 rad/s below the resonance at 300 rad/s."""
    JM = JL = 1e-3
    k = 45.0
    c = 2 * 0.02 * np.sqrt(k * JM * JL / (JM + JL))
    return control.tf([JL, c, k], np.polymul([1.0, 0.0], [JM * JL, (JM + JL) * c, (JM + JL) * k]))


def _two_mass_position() -> control.TransferFunction:
    """Load position over force on the other mass (unit masses, the spring for 150 rad/s, zeta 0.01): the
    non-collocated ``(c s + k) / (s^2 (s^2 + 2 (c s + k)))``."""
    k = 150.0**2 / 2
    c = 0.01 * 150.0
    return control.tf([c, k], np.polymul([1.0, 0.0, 0.0], [1.0, 2 * c, 2 * k]))


def _axial_mode() -> control.TransferFunction:
    w, z, p = 2 * np.pi * 200.0, 0.01, 2 * np.pi * 500.0
    return control.tf([w**2], np.polymul([1.0 / p, 1.0], [1.0, 2 * z * w, w**2]))


def _measured(G: control.TransferFunction, delay: float, seed: int) -> control.FrequencyResponseData:
    """``G e^{-s delay}`` at 250 points a decade over five decades about its poles, with 1 % complex noise."""
    poles = np.abs(G.poles())
    lo, hi = np.log10(poles.min()) - 2.5, np.log10(poles.max()) + 2.5
    w = np.logspace(lo, hi, int(CHECK_PER_DECADE * (hi - lo)) + 1)
    rng = np.random.default_rng(seed)
    noise = 1.0 + 0.01 * (rng.standard_normal(w.size) + 1j * rng.standard_normal(w.size)) / np.sqrt(2)
    return control.frd(G(1j * w) * np.exp(-1j * w * delay) * noise, w)


def practice() -> list[Case]:
    s = control.tf("s")
    fotd2 = 1 / (s + 1) ** 2
    axial = _axial_mode()
    return [
        Case("near-int 1e3", 1 / ((1000 * s + 1) * (s + 1)), 0.0, Mks=50.0, source="Skogestad 2003 (SIMC)"),
        Case("near-int 1e4 L", 1 / ((1e4 * s + 1) * (s + 1)), 0.1, Mks=50.0, source="Skogestad 2003 (SIMC)"),
        Case("near-int 1e4 Ts", 1 / ((1e4 * s + 1) * (s + 1)), 0.1, Mks=50.0, Ts=0.01,
             source="Skogestad 2003 (SIMC)"),
        Case("two-mass speed", _two_mass_speed(), 0.001, Mks=1.0, source="Ellis (resonant load)"),
        Case("two-mass position", _two_mass_position(), 0.0, Ms=1.6, Mt=1.6, Mks=2e4,
             source="Franklin, Powell, Emami-Naeini (non-collocated two-mass)"),
        Case("screw axial mode", axial, 2e-4, Mks=5.0, source="ball-screw first axial mode (paper eq. (1))"),
        Case("unstable 1", 1 / (s - 1), 0.1, Ms=1.6, Mt=1.6, Mks=10.0, source="De Paor and O'Malley 1989"),
        Case("unstable 2", 1 / ((5 * s - 1) * (2.07 * s + 1)), 0.939, Ms=2.0, Mt=2.0, Mks=10.0,
             source="Huang and Chen 1997"),
        Case("delay-dominant", 1 / ((s + 1) * (0.5 * s + 1)), 5.0, source="Astrom and Hagglund 2006"),
        Case("high order", (-0.3 * s + 1) * (0.08 * s + 1) / ((2 * s + 1) * (s + 1) * (0.4 * s + 1) * (0.2 * s + 1)
                                                              * (0.05 * s + 1) ** 3), 0.0,
             source="Skogestad 2003 (half rule)"),
        Case("nmp zero", (-2 * s + 1) / ((s + 1) * (0.5 * s + 1) ** 2), 0.0, source="Astrom and Hagglund 2006"),
        Case("integrating lag", 1 / (s * (2 * s + 1)), 0.5, source="Skogestad 2003 (SIMC)"),
        Case("oscillatory 0.02", 4 / ((s + 1) * (s**2 + 0.08 * s + 4)), 0.0, source="Astrom and Hagglund 2000 (P7)"),
        Case("frd fotd noise", _measured(fotd2, 1.0, 1), 0.0, source="AH P2 T=1, measured", model=(fotd2, 1.0)),
        Case("frd resonant noise", _measured(axial, 2e-4, 2), 0.0, Mks=5.0, source="axial mode, measured",
             model=(axial, 2e-4)),
        Case("lag3 delay Ts", 1 / (s + 1) ** 3, 0.2, Mks=4.0, Ts=0.01, source="issue example"),
        Case("PI unstable Ts", 1 / (s - 1), 0.1, Ms=1.6, Mt=1.6, Mks=None, form="PI", Ts=0.02,
             source="De Paor and O'Malley 1989"),
    ]


PEER_GRID = 2 * np.pi * np.logspace(-2, 2, 1000)
_TWO_INERTIA_A = [[0, 1, 0, 0], [-100, -2, 100, 1], [0, 0, 0, 1], [100, 1, -100, -2]]


def peer_plants() -> list[Case]:
    """The commercial peer's own test plants the issue names, as state space, on the peer's grid: a near-integrating
    second-order plant (poles at 1e-5 and 0.12 rad/s) and the two-inertia plant (unit inertias, shaft 100, dampings
    1) with the output on the motor and on the load; the reference a PID with the peer's second-order filter."""
    src = "the commercial peer's test plants (issue 43)"
    near = control.ss([[0, 1], [-1.2e-6, -0.12001]], [[0], [1]], [[11.2, 0]], 0)
    motor = control.ss(_TWO_INERTIA_A, [[0], [1], [0], [0]], [[1, 0, 0, 0]], 0)
    load = control.ss(_TWO_INERTIA_A, [[0], [1], [0], [0]], [[0, 0, 1, 0]], 0)
    return [
        Case("peer near-integrating", near, 0.0, Ms=1.2, Mt=1.2, Mks=100.0, w=PEER_GRID, ref_form="PID2", source=src),
        Case("peer two-inertia motor", motor, 0.0, Ms=1.3, Mt=1.5, Mks=300.0, w=PEER_GRID, ref_form="PID2",
             source=src),
        Case("peer two-inertia load", load, 0.0, Ms=1.3, Mt=1.5, Mks=300.0, w=PEER_GRID, ref_form="PID2",
             source=src + ", output on the load"),
    ]


def sampled() -> list[Case]:
    """Sampled loops with long delays (1 to 10,000 samples, sample periods 1e-4 to 0.1 s), each on the exact
    zero-order-hold loop; the plants are the classes above (first and second order with delay, integrating, the
    issue's double integrator with a resonance), their parameters chosen here."""
    s = control.tf("s")
    src = "sampled, long delay (chosen here)"
    dint = 1 / (2.8144773233982723e-05 * s**4 + 0.00021220659078919382 * s**3 + s**2)

    def case(name: str, G: Any, d: int, Ts: float, **kw: Any) -> Case:
        return Case(name, G, d * Ts, Ts=Ts, sampled_set=True, source=src, **kw)

    return [
        case("S fopdt 10000 @ 1e-4", 1 / (s + 1), 10000, 1e-4),
        case("S fopdt 100 @ 1e-4", 1 / (0.1 * s + 1), 100, 1e-4),
        case("S issue 5000 @ 1e-3", 2 / (50 * s + 1), 5000, 1e-3, Mt=None, Mks=None),
        case("S issue 100 @ 1e-3", 2 / (10 * s + 1), 100, 1e-3, Mt=None, Mks=100.0),
        case("S sotd 1 @ 1e-3", 1 / ((0.05 * s + 1) * (0.01 * s + 1)), 1, 1e-3),
        case("S sotd 1000 @ 1e-2", 1 / ((s + 1) * (0.2 * s + 1)), 1000, 1e-2),
        case("S lag2 10 @ 0.1", 1 / (5 * s + 1) ** 2, 10, 0.1),
        case("S fopdt 3 @ 0.1", 1 / (10 * s + 1), 3, 0.1),
        case("S integrating 2000 @ 1e-3", 1 / (s * (s + 1)), 2000, 1e-3, Mks=20.0),
        case("S fopdt 10000 @ 1e-3", 1 / (2 * s + 1), 10000, 1e-3),
        case("S double integrator 3 @ 1e-3", dint, 3, 1e-3, Mt=None, Mks=20.0),
    ]


# --------------------------------------------------------------------------------------
# the plant and the controller, written here (python-control for the plant)
# --------------------------------------------------------------------------------------
def _roots(case: Case) -> np.ndarray:
    G = case.model[0] if case.measured else case.G
    r = np.concatenate([G.poles(), G.zeros()])
    return r[np.abs(r) > 1e-12]


def _span(case: Case) -> tuple[float, float]:
    """Three decades beyond the plant's poles, zeros and delay each side (a sampled loop: to its Nyquist
    frequency)."""
    if case.measured:
        return float(case.G.omega[0]), float(case.G.omega[-1])
    mags = np.abs(_roots(case))
    if case.delay > 0:
        mags = np.append(mags, 1.0 / case.delay)
    lo, hi = mags.min() * 1e-3, mags.max() * 1e3
    if case.Ts is not None:
        hi = 0.9999 * np.pi / case.Ts
    return lo, hi


def grid(case: Case, per_decade: int, cluster: int) -> np.ndarray:
    """Log-spaced over :func:`_span`, with ``cluster`` points across each lightly damped pole or zero pair; a grid
    given: itself at the reference's density, ten times as many points over its range at the check's."""
    if case.w is not None:
        w = np.asarray(case.w, float)
        if per_decade <= PER_DECADE_REF:
            return w
        return np.logspace(np.log10(w[0]), np.log10(w[-1]), 10 * w.size)
    if case.measured:
        return np.asarray(case.G.omega, float)
    lo, hi = _span(case)
    parts = [np.logspace(np.log10(lo), np.log10(hi), int(per_decade * np.log10(hi / lo)) + 1)]
    for r in _roots(case):
        wn, zeta = abs(r), -r.real / abs(r)
        if r.imag > 0 and abs(zeta) < 0.3:
            parts.append(np.linspace(wn * (1 - 10 * abs(zeta)), wn * (1 + 10 * abs(zeta)), cluster))
    w = np.unique(np.concatenate(parts))
    return w[(w >= lo) & (w <= hi)]


def plant_response(case: Case, w: np.ndarray) -> np.ndarray:
    """The plant on the axis: python-control's transfer function (its zero-order-hold equivalent on a sampled
    loop, the delay in whole samples), measured data as given."""
    if case.measured:
        return np.asarray(case.G.eval(w), complex).ravel()
    if case.Ts is None:
        return case.G(1j * w) * np.exp(-1j * w * case.delay)
    d = int(round(case.delay / case.Ts))
    Gd = control.c2d(case.G, case.Ts, "zoh")
    z = np.exp(1j * w * case.Ts)
    return Gd(z) * z ** (-d)


def controller_response(theta: np.ndarray, w: np.ndarray, case: Case) -> tuple[np.ndarray, list[np.ndarray]]:
    """``C`` of ``kp + ki/s + kd s/(Tf s + 1)`` (the log-gains ``theta``), and its derivatives in ``theta``; a
    sampled loop's: the controller step's (trapezoidal integral, derivative through a backward-Euler filter)."""
    g = np.exp(theta)
    kp, ki = g[0], g[1]
    if case.Ts is None:
        s = 1j * w
        I = 1 / s
        if case.form == "PI":
            return kp + ki * I, [kp + 0 * s, ki * I]
        if case.form == "PID2":  # (kp + ki/s + kd s) F(s), F = 1 / (1 + Tf s + (Tf s)^2 / 2)
            kd, Tf = g[2], g[3]
            F = 1 / (1 + Tf * s + (Tf * s) ** 2 / 2)
            N = kp + ki * I + kd * s
            return N * F, [kp * F, ki * I * F, kd * s * F, -N * (Tf * s + (Tf * s) ** 2) * F**2]
        kd, Tf = g[2], g[3]
        D = s / (Tf * s + 1)
        return kp + ki * I + kd * D, [kp + 0 * s, ki * I, kd * D, -kd * Tf * s * D / (Tf * s + 1)]
    Ts = case.Ts
    zi = np.exp(-1j * w * Ts)
    I = Ts / 2 * (1 + zi) / (1 - zi)
    if case.form == "PI":
        return kp + ki * I, [kp + 0 * zi, ki * I]
    kd, Tf = g[2], g[3]
    a = Tf / (Tf + Ts)
    D = (1 - a) / Ts * (1 - zi) / (1 - a * zi)
    dD = -(1 - zi) / Ts * (1 - zi) / (1 - a * zi) ** 2 * a * (1 - a)  # dD/dlog Tf
    return kp + ki * I + kd * D, [kp + 0 * zi, ki * I, kd * D, kd * dD]


def bound_rows(C: np.ndarray, G: np.ndarray, case: Case, dC: list[np.ndarray] | None = None) -> tuple[Any, Any]:
    """``|X| / M`` stacked over the bounds set (``|S|``, ``|T|``, ``|KS|``); with ``dC`` (the derivatives of ``C``),
    the gradients of ``1 - |X|^2 / M^2`` too."""
    L = C * G
    d2 = np.abs(1 + L) ** 2
    parts, grads = [], []
    for kind, M in (("S", case.Ms), ("T", case.Mt), ("KS", case.Mks)):
        if M is None:
            continue
        num2 = {"S": np.ones_like(d2), "T": np.abs(L) ** 2, "KS": np.abs(C) ** 2}[kind]
        parts.append(np.sqrt(num2 / d2) / M)
        if dC is None:
            continue
        D = np.asarray(dC)  # (variables, frequencies)
        dd2 = 2 * np.real(np.conj(1 + L) * G * D)
        dn2 = {"S": np.zeros_like(dd2), "T": 2 * np.real(np.conj(L) * G * D), "KS": 2 * np.real(np.conj(C) * D)}[kind]
        grads.append((-(dn2 * d2 - num2 * dd2) / d2**2 / M**2).T)
    return np.concatenate(parts), (np.concatenate(grads) if dC is not None else None)


def stable(case: Case, kp: float, ki: float, kd: float, Tf: float) -> bool:
    """The closed loop's poles by python-control, in state space (a transfer function's roots lose the slow poles'
    digits where they cluster near ``s = 0`` or ``z = 1``): the eigenvalues of the loop of the plant's state space
    (a 12th-order Padé of a delay; a sampled loop's zero-order hold, its whole-sample delay as states) and the
    controller's; a measured plant: the model it was measured from."""
    G, delay = (case.model if case.measured else (case.G, case.delay))
    if case.Ts is None:
        C = control.tf([kp * Tf + kd, kp + ki * Tf, ki], [Tf, 1.0, 0.0]) if case.form == "PID" else \
            control.tf([kd, kp, ki], [Tf**2 / 2, Tf, 1.0, 0.0]) if case.form == "PID2" else \
            control.tf([kp, ki], [1.0, 0.0])
        P = control.ss(G)
        if delay > 0:
            P = P * control.ss(control.tf(*control.pade(delay, 12)))
        return bool(np.all(np.linalg.eigvals(control.feedback(P * control.ss(C), 1).A).real < 0))
    Ts = case.Ts
    d = int(round(delay / Ts))
    P = control.c2d(control.ss(G), Ts, "zoh")
    if d > 50:
        return _sampled_nyquist_stable(case, kp, ki, kd, Tf)
    if d:
        P = P * control.ss(control.tf([1.0], [1.0] + [0.0] * d, Ts))
    a = Tf / (Tf + Ts) if case.form == "PID" else 0.0
    gd = kd * (1 - a) / Ts if case.form == "PID" else 0.0
    num = (kp * np.polymul([1, -1], [1, -a]) + ki * Ts / 2 * np.polymul([1, 1], [1, -a])
           + gd * np.polymul([1, -1], [1, -1]))
    C = control.ss(control.tf(num, np.polymul([1, -1], [1, -a]), Ts))
    return bool(np.all(np.abs(np.linalg.eigvals(control.feedback(P * C, 1).A)) < 1))


def _sampled_nyquist_stable(case: Case, kp: float, ki: float, kd: float, Tf: float) -> bool:
    """A sampled loop with a long delay (its delay line would be thousands of states): the Nyquist criterion on
    python-control's zero-order-hold equivalent times ``z^-d``, the unit circle's upper half at 8 points per
    sample of delay (``z^-d`` turns a sixteenth of a turn between them) and log-spaced below, the integrators
    (the plant's and the controller's) indented; the open loop's unstable poles from the sampled plant's."""
    Ts = case.Ts
    if Ts is None:
        raise ValueError(f"{case.name}: the Nyquist check is for a sampled loop, and the case has no sample period")
    d = int(round(case.delay / Ts))
    Gd = control.c2d(case.G, Ts, "zoh")
    top = np.pi / Ts
    w = np.unique(np.concatenate([np.logspace(np.log10(top) - 12, np.log10(top / (4 * d)), 2000),
                                  np.linspace(top / (4 * d), top, 8 * d)]))
    th = np.log([kp, ki] + ([max(kd, 1e-300), Tf] if case.form == "PID" else []))
    z = np.exp(1j * w * Ts)
    L = controller_response(th, w, case)[0] * Gd(z) * z ** (-d)
    f = 1 + L
    half = np.sum(np.angle(f[1:] * np.conj(f[:-1])))
    poles = Gd.poles()
    m = int(np.sum(np.abs(poles - 1) < 1e-5)) + 1  # a double pole at z = 1 comes out split by about 1e-7
    p = int(np.sum((np.abs(poles) > 1 + 1e-9) & (np.abs(poles - 1) >= 1e-5)))
    return bool(np.round(p - (2 * half - m * np.pi) / (2 * np.pi)) == 0)


# --------------------------------------------------------------------------------------
# the reference: a dense multi-start, SLSQP in log-gains
# --------------------------------------------------------------------------------------
def _scales(case: Case) -> list[tuple[float, float]]:
    """Frequencies and gains from the plant: the geometric middle of its poles', zeros' and delay's frequencies, and
    a fifth of the lowest of them (a plant whose phase starts at -180 degrees is controlled below its first pole or
    resonance); each at most its Nyquist frequency, with ``1/|G|`` there."""
    mags = np.abs(_roots(case))
    delay = case.model[1] if case.measured else case.delay
    if delay > 0:
        mags = np.append(mags, 1.0 / delay)
    out = []
    picks = [float(np.exp(np.mean(np.log(mags)))), 0.2 * float(mags.min())]
    if case.w is not None:  # a grid given: five frequencies across it too (the loop may cross over anywhere on it)
        picks += [float(np.quantile(case.w, q)) for q in (0.1, 0.3, 0.5, 0.7, 0.9)]
    if case.Mks is not None and not case.measured:  # a third of where Mks |G| falls through 1: the highest crossover
        lo, hi = _span(case)
        wk = np.logspace(np.log10(lo), np.log10(hi), 400)
        above = np.flatnonzero(case.Mks * np.abs(plant_response(case, wk)) >= 1)
        if above.size and above[-1] < wk.size - 1:
            picks.append(float(wk[above[-1]]) / 3)
    for w in picks:
        if case.Ts is not None:
            w = min(w, 0.3 / case.Ts)
        if case.measured:  # the nearest measured point
            w = float(case.G.omega[np.argmin(np.abs(np.log(case.G.omega / w)))])
        out.append((w, float(1.0 / np.abs(plant_response(case, np.array([w]))[0]))))
    return out


def _near_peaks(r: np.ndarray, above: float) -> np.ndarray:
    """The grid points within three of a local maximum of any bound's ``|X| / M`` above ``above`` (``r``: a row per
    bound)."""
    peak = np.zeros(r.shape, bool)
    peak[:, 1:-1] = (r[:, 1:-1] > r[:, :-2]) & (r[:, 1:-1] >= r[:, 2:])  # a plateau counts once, at its start
    peak[:, 0], peak[:, -1] = r[:, 0] >= r[:, 1], r[:, -1] > r[:, -2]
    hit = np.any(peak & (r > above), axis=0)
    near = hit.copy()
    for k in range(1, 4):
        near[k:] |= hit[:-k]
        near[:-k] |= hit[k:]
    return near


def _minus_ki(t: np.ndarray) -> float:
    """The reference's objective: ``-log ki`` (the second parameter)."""
    return -float(t[1])


def _minus_ki_gradient(t: np.ndarray) -> np.ndarray:
    g = np.zeros(t.size)
    g[1] = -1.0
    return g


#: SLSQP's options for the reference (typed loosely: the stubs' TypedDict names only some of them)
_SLSQP_OPTIONS: Any = {"maxiter": 200, "ftol": 1e-12}


def _solve(case: Case, w: np.ndarray, G: np.ndarray, th0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """SLSQP from ``th0`` (a stable loop) for the largest ``log ki`` under every bound on the grid ``w``, by
    exchange in a trust region (SLSQP's own subproblem grows fast with its rows): the rows about each peak of
    ``|X| / M`` above 0.85, the step at most ``r`` (1.5 to start) in each log-gain. A step that breaks a bound
    elsewhere on the grid adds the rows about those peaks and is taken again; one to an unstable loop (python-control's
    poles) halves ``r``; one that ends on the region's edge moves it and doubles ``r`` (at most 3)."""
    def rows(th: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        ww, gg = (w, G) if idx is None else (w[idx], G[idx])
        return bound_rows(controller_response(th, ww, case)[0], gg, case)[0]

    nb = rows(th0).size // w.size
    th, r = th0, 1.5
    active = _near_peaks(rows(th).reshape(nb, -1), 0.85)
    for _ in range(60):
        idx = np.flatnonzero(active)

        def cons(t: np.ndarray, idx: np.ndarray = idx) -> np.ndarray:
            return 1.0 - rows(t, idx) ** 2

        def jac(t: np.ndarray, idx: np.ndarray = idx) -> np.ndarray:
            C, dC = controller_response(t, w[idx], case)
            return bound_rows(C, G[idx], case, dC)[1]

        box = list(zip(np.maximum(lo, th - r), np.minimum(hi, th + r)))
        constraints: list[Any] = [{"type": "ineq", "fun": cons, "jac": jac}] if idx.size else []
        new = minimize(_minus_ki, th, jac=_minus_ki_gradient, method="SLSQP", bounds=box,
                       constraints=constraints,
                       options=_SLSQP_OPTIONS).x
        full = rows(new).reshape(nb, -1)
        over = _near_peaks(full, 1.0 + 1e-9)
        if np.any(over & ~active):  # broke a bound the solve did not hold: hold it and solve again
            active |= over
            continue
        if not stable(case, *_gains(new)):  # left the stable loops: a shorter step
            r /= 2.0
            if r < 0.01:
                break
            continue
        edge = np.any((np.abs(new - th) > r - 1e-6) & (new > lo + 1e-9) & (new < hi - 1e-9))
        th = new
        active |= _near_peaks(full, 0.85)
        if not edge:
            break
        r = min(2.0 * r, 3.0)
    return th


def _gains(th: np.ndarray) -> tuple[float, float, float, float]:
    g = np.exp(th)
    return (g[0], g[1], g[2], g[3]) if th.size == 4 else (g[0], g[1], 0.0, 1.0)


def _low(case: Case, w0: float) -> tuple[np.ndarray, np.ndarray]:
    """Eight decades below ``w0`` (where an integrating loop's gain grows to its asymptote) and the plant there (a
    measured plant's model)."""
    wl = np.logspace(np.log10(w0) - 8, np.log10(w0), 41)[:-1]
    if case.measured:
        G, delay = case.model
        return wl, G(1j * wl) * np.exp(-1j * wl * delay)
    return wl, plant_response(case, wl)


def _screen(case: Case, cand: np.ndarray, w: np.ndarray, G: np.ndarray, wl: np.ndarray,
            Gl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every candidate at once: the worst ``|X| / M`` on the grid, and whether the loop is stable by the Nyquist
    criterion (the argument of ``1 + L`` from eight decades below the grid to its end, the integrators indented, a
    continuous loop's end closed where ``|L| < 1``; unknown, so not stable, where it is not)."""
    th = cand.T[:, :, None]  # (gains, candidates, 1)
    C = controller_response(th, w, case)[0]
    L = C * G
    d = np.abs(1 + L)
    worst = np.max(1 / d, axis=1) / case.Ms
    if case.Mt is not None:
        worst = np.maximum(worst, np.max(np.abs(L) / d, axis=1) / case.Mt)
    if case.Mks is not None:
        worst = np.maximum(worst, np.max(np.abs(C) / d, axis=1) / case.Mks)
    Lc = np.concatenate([controller_response(th, wl, case)[0] * Gl, L], axis=1)
    f = 1 + Lc
    turn = np.unwrap(np.angle(f), axis=1)
    half = turn[:, -1] - turn[:, 0]
    closed = np.ones(len(cand), bool)
    if case.Ts is None:
        half = half - np.angle(f[:, -1])
        closed = np.abs(Lc[:, -1]) < 1
    G0, _ = case.model if case.measured else (case.G, None)
    m = int(np.sum(np.abs(G0.poles()) < 1e-9)) + 1
    if case.Ts is None:
        p = int(np.sum(G0.poles().real > 1e-9))
    else:  # a double pole at z = 1 comes out of c2d split by about 1e-7 about it: an integrator pair, not unstable
        zp = control.c2d(G0, case.Ts, "zoh").poles()
        p = int(np.sum((np.abs(zp) > 1 + 1e-9) & (np.abs(zp - 1) > 1e-5)))
    return worst, closed & (np.round(p - (2 * half - m * np.pi) / (2 * np.pi)) == 0)


def reference(case: Case, rng: np.random.Generator) -> dict[str, Any]:
    """The best of :data:`REF_STARTS` SLSQP solves (see the module docstring), in the case's reference form."""
    if case.ref_form is not None:
        case = replace(case, form=case.ref_form)
    w = grid(case, PER_DECADE_REF, 400)
    G = plant_response(case, w)
    wl, Gl = _low(case, w[0])
    n = 2 if case.form == "PI" else 4
    boxes = [(np.log([kr * 1e-4, kr * wr * 1e-5, kr / wr * 1e-4, 1e-5 / wr][:n]),
              np.log([kr * 1e3, kr * wr * 1e3, kr / wr * 1e3, 1e2 / wr][:n])) for wr, kr in _scales(case)]
    lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
    cand = np.concatenate([b[0] + qmc.LatinHypercube(d=n, seed=rng).random(REF_CANDIDATES // len(boxes)) * (b[1] - b[0])
                           for b in boxes])
    worst_all, stable_all = _screen(case, cand, w, G, wl, Gl)

    def worst(th: np.ndarray) -> float:
        return float(np.max(bound_rows(controller_response(th, w, case)[0], G, case)[0]))

    # the stable candidates, those meeting the bounds by largest ki, then the rest by least violation; each start
    # confirmed stable by python-control's poles
    order = sorted(np.flatnonzero(stable_all), key=lambda i: (worst_all[i] > 1.0, worst_all[i] if worst_all[i] > 1.0
                                                              else -cand[i, 1]))
    starts: list[np.ndarray] = []
    for i in order:
        if len(starts) == REF_STARTS:
            break
        if stable(case, *_gains(cand[i])):
            starts.append(cand[i])
    best: dict[str, Any] = {"ki": None, "starts": len(starts), "solved": 0, "stable_candidates": int(stable_all.sum())}
    for th0 in starts:
        th = _solve(case, w, G, th0, lo, hi)
        if worst(th) > 1.0 + 1e-6:
            continue
        g = np.exp(th)
        gains = _gains(th)
        if not stable(case, *gains):
            continue
        best["solved"] += 1
        if best["ki"] is None or g[1] > best["ki"]:
            best.update(ki=float(g[1]), kp=float(g[0]), kd=float(gains[2]), Tf=float(gains[3]))
    return best


# --------------------------------------------------------------------------------------
# ours
# --------------------------------------------------------------------------------------
def tune(case: Case, solver: str) -> Any:
    return autotune(case.G, Ms=case.Ms, Mt=case.Mt, Mks=case.Mks, delay_s=case.delay, form=case.form, Ts=case.Ts,
                    loop=None if case.Ts is None else "sampled", solver=solver, w=case.w)


def timed(case: Case, solver: str) -> tuple[Any, list[float], list[float]]:
    """The result of :data:`REPEATS` runs and each run's wall and CPU (this process) seconds."""
    times, cpu, result = [], [], None
    for _ in range(REPEATS):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            result = tune(case, solver)
        except Exception as exc:  # recorded, not hidden: a failure counts against the batch
            print(f"  {solver}: no result ({type(exc).__name__}: {exc})", flush=True)
            return None, [time.perf_counter() - t0], [time.process_time() - c0]
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return result, times, cpu


def check(case: Case, r: Any) -> tuple[float, bool]:
    """The worst ``|X| / M - 1`` on the check grid (ten times the tuner's density) and the loop's stability, both
    from the gains alone (``kp, ki, kd, Tf`` of ``kp + ki/s + kd s/(Tf s + 1)``)."""
    c = r.controller_
    kp, ki, kd, Tf = c.kp, c.ki, c.kd, c.Tf
    w = grid(case, CHECK_PER_DECADE, 2000)
    if case.w is not None:  # a grid given: on it and on one ten times denser
        w = np.union1d(w, case.w)
    th = np.log([kp, ki] + ([max(kd, 1e-300), max(Tf, 1e-300)] if case.form == "PID" else []))
    rows = bound_rows(controller_response(th, w, case)[0], plant_response(case, w), case)[0]
    return float(np.max(rows) - 1.0), stable(case, kp, ki, kd, Tf if case.form == "PID" else 1.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", help="run the plants whose name contains this")
    parser.add_argument("--blas-threads", metavar="N", default="1",
                        help="OpenBLAS threads (default 1; give it as --blas-threads=N: it is read before numpy loads)")
    parser.add_argument("--write-docs", action="store_true",
                        help="write the figures' table into docs/autotune.md (between its markers)")
    args = parser.parse_args()
    cases = [c for c in astrom_hagglund() + practice() + peer_plants() + sampled()
             if args.only is None or args.only in c.name]
    load = os.getloadavg()[0]
    rng = np.random.default_rng(20240601)
    rows, first = [], None
    for case in cases:
        t0 = time.perf_counter()
        ref = reference(case, rng)
        ref_s = time.perf_counter() - t0
        ours, t_ours, c_ours = timed(case, "sqp")
        first = first if first is not None else t_ours[0]
        peer, t_peer, _ = timed(case, "slsqp")
        row: dict[str, Any] = {"plant": case.name, "source": case.source, "ref_ki": ref["ki"], "ref_s": ref_s,
                               "sampled_set": case.sampled_set, "peer": case.ref_form is not None,
                               "s": statistics.median(t_ours), "cpu_s": statistics.median(c_ours),
                               "slsqp_s": statistics.median(t_peer), "slsqp_ki": None if peer is None else peer.ki}
        if ours is not None:
            violation, ok = check(case, ours)
            row.update(ki=ours.ki, violation=violation, stable=ok and ours.stable, leans_on=list(ours.leans_on),
                       ratio=None if ref["ki"] is None else ours.ki / ref["ki"])
        else:
            row.update(ki=None, violation=None, stable=False, ratio=None)
        rows.append(row)
        print(_line(case, row, ref), flush=True)
    figures = summary(rows)
    figures["first_call_s"] = first
    figures["loadavg_1min"] = load
    figures["openblas_num_threads"] = os.environ.get("OPENBLAS_NUM_THREADS")
    if args.write_docs:
        write_docs(figures)
    print(json.dumps(figures))


def _line(case: Case, row: dict[str, Any], ref: dict[str, Any]) -> str:
    def fmt(x: float | None) -> str:
        return "-" if x is None else f"{x:.5g}"

    return (f"{case.name:20s} ki {fmt(row['ki']):>10s} ref {fmt(ref['ki']):>10s} ({ref['solved']}/{ref['starts']} "
            f"solved, {row['ref_s']:5.1f} s) ratio {fmt(row['ratio']):>7s} viol {fmt(row['violation']):>10s} "
            f"{'stable' if row['stable'] else 'UNSTABLE'} {row['s'] * 1e3:6.1f} ms (CPU {row['cpu_s'] * 1e3:6.1f} "
            f"ms; SLSQP {row['slsqp_s'] * 1e3:6.1f} ms, ki {fmt(row['slsqp_ki'])})")


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ratios = [r["ratio"] for r in rows]
    times, cpu = [r["s"] for r in rows], [r["cpu_s"] for r in rows]
    return {
        "plants": len(rows),
        "ki_over_reference_min": None if any(x is None for x in ratios) else min(ratios),
        "ki_over_reference_median": None if any(x is None for x in ratios) else statistics.median(ratios),
        "no_result": [r["plant"] for r in rows if r["ki"] is None],
        "no_reference": [r["plant"] for r in rows if r["ref_ki"] is None],
        "below_reference": [r["plant"] for r in rows if r["ratio"] is not None and r["ratio"] < 0.99],
        "bound_violation_max": max((r["violation"] for r in rows if r["violation"] is not None), default=None),
        "all_stable": all(r["stable"] for r in rows),
        "median_s_per_plant": statistics.median(times),
        "worst_s_per_plant": max(times),
        "sampled_worst_s": max((r["s"] for r in rows if r.get("sampled_set")), default=None),
        "sampled_ki_over_reference_min": min((r["ratio"] for r in rows if r.get("sampled_set") and r["ratio"]),
                                             default=None),
        "peer_ki_over_reference_min": min((r["ratio"] for r in rows if r.get("peer") and r["ratio"]), default=None),
        "median_cpu_s_per_plant": statistics.median(cpu),
        "worst_cpu_s_per_plant": max(cpu),
        "autotune_vs_slsqp_time_ratio": sum(times) / sum(r["slsqp_s"] for r in rows),
        "autotune_vs_slsqp_time_ratio_median": statistics.median(r["s"] / r["slsqp_s"] for r in rows),
        "slsqp_no_result": [r["plant"] for r in rows if r["slsqp_ki"] is None],
        "ki_over_slsqp_min": min((r["ki"] / r["slsqp_ki"] for r in rows if r["ki"] and r["slsqp_ki"]), default=None),
        "leaning_on_defaults": [r["plant"] for r in rows if r.get("leans_on")],
    }


_BEGIN = ("<!-- benchmark table: written by `python benchmarks/autotune.py --write-docs` from its last line; "
          "do not edit -->")
_END = "<!-- end of benchmark table -->"


def table(f: dict[str, Any]) -> str:
    """The docs page's table of the figures (the last line's keys)."""
    def x(v: Any, spec: str) -> str:
        return "-" if v is None else format(v, spec)

    rows = [
        ("our ki over the reference's, least over the batch (`ki_over_reference_min`)",
         x(f["ki_over_reference_min"], ".4f") + f" (median {x(f['ki_over_reference_median'], '.4f')})", ">= 0.99"),
        ("worst bound over its limit on a grid ten times the tuner's (`bound_violation_max`)",
         x(f["bound_violation_max"], ".1e"), "<= 0.005"),
        ("every loop stable, python-control's poles (`all_stable`)", str(f["all_stable"]).lower(), "true"),
        ("the peer's plants and the sampled long-delay loops: our ki over the reference's, least "
         "(`peer_ki_over_reference_min`, `sampled_ki_over_reference_min`)",
         f"{x(f['peer_ki_over_reference_min'], '.4f')}, {x(f['sampled_ki_over_reference_min'], '.4f')}",
         ">= 0.99"),
        ("the slowest sampled long-delay loop (`sampled_worst_s`)", x(f["sampled_worst_s"], ".3f") + " s",
         "<= 0.5 s"),
        ("time per plant, median and worst of the per-plant medians of three (`median_s_per_plant`, "
         "`worst_s_per_plant`)", f"{x(f['median_s_per_plant'], '.3f')} s, {x(f['worst_s_per_plant'], '.3f')} s",
         "<= 0.05 s, <= 0.5 s"),
        ("the same in CPU seconds of this process (`median_cpu_s_per_plant`, `worst_cpu_s_per_plant`)",
         f"{x(f['median_cpu_s_per_plant'], '.3f')} s, {x(f['worst_cpu_s_per_plant'], '.3f')} s", ""),
        ("our time over SLSQP's on the same problem, summed over the batch (`autotune_vs_slsqp_time_ratio`); the "
         "median of the plants' own ratios (`autotune_vs_slsqp_time_ratio_median`)",
         f"{x(f['autotune_vs_slsqp_time_ratio'], '.2f')}; {x(f['autotune_vs_slsqp_time_ratio_median'], '.2f')}"
         + (f" (SLSQP found nothing on {', '.join(f['slsqp_no_result'])})" if f["slsqp_no_result"] else ""),
         "<= 0.5 (an aim)"),
        ("the first plant's first call, the compiled functions built (`first_call_s`)", x(f["first_call_s"], ".2f")
         + " s", ""),
        ("the machine's load, one-minute average (`loadavg_1min`)", x(f["loadavg_1min"], ".1f"), ""),
    ]
    lines = [f"{f['plants']} plants.", "", "| figure (key) | measured | target |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join(lines)


def write_docs(f: dict[str, Any], path: str = os.path.join(os.path.dirname(__file__), "..", "docs",
                                                              "autotune.md")) -> None:
    """Replace the table between the docs page's markers with :func:`table` of ``f``."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    head, rest = text.split(_BEGIN, 1)
    _, tail = rest.split(_END, 1)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(head + _BEGIN + "\n" + table(f) + "\n" + _END + tail)


if __name__ == "__main__":
    main()
