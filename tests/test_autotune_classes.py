"""The autotuner on one plant of each class practice brings, against an exhaustive search written here.

For a PI the problem has two gains, so an exhaustive search is cheap and independent of the tuner: the plant's
response from python-control on a dense grid (2,000 log-spaced points over three decades beyond its poles and zeros
each side, and 400 across each lightly damped pair), for each of 120 proportional gains the largest integral gain
below the first bound it breaks (a log scan up, then bisection: ``ki`` between zero and it meets every bound), the best
proportional gain's bracket searched again twice, 120 times finer each, and the loop's stability from
python-control's closed-loop poles (in state space, a 12th-order Padé of a delay). The tolerance: the search's
proportional gain ends within 1e-4 (relative) of its best, where the integral gain is flat to first order, and its
bisection to 1e-12, so its ki is within 1e-4 of the optimum on its grid; the tuner holds the bounds within 1e-4 on
a grid ten times its own (which moves ki by about as much). ``rel=2e-3`` covers both with a margin; a tuner that
ended in another local optimum, or a bound broken between its grid points, misses it by more (the batch's local
optima differ by percent).

The classes: integrating and near-integrating (poles decades apart), lightly damped resonant (a
two-inertia drive, an oscillatory lag), open-loop unstable, delay-dominant, high-order, non-minimum phase, and a
measured frequency response with noise.
"""

import control
import numpy as np
import pytest

from piezopreload.tuning.autotune import TOLERANCE, autotune

s = control.tf("s")


def _grid(G: control.TransferFunction, delay: float) -> np.ndarray:
    r = np.concatenate([G.poles(), G.zeros()])
    mags = np.abs(r[np.abs(r) > 1e-12])
    if delay:
        mags = np.append(mags, 1 / delay)
    w = [np.logspace(np.log10(mags.min()) - 3, np.log10(mags.max()) + 3, 2000)]
    for root in r:
        if root.imag > 0 and abs(root.real / abs(root)) < 0.3:
            zeta = -root.real / abs(root)
            w.append(np.linspace(abs(root) * (1 - 10 * abs(zeta)), abs(root) * (1 + 10 * abs(zeta)), 400))
    return np.unique(np.concatenate(w))


def _stable(G: control.TransferFunction, delay: float, kp: float, ki: float) -> bool:
    """python-control's closed-loop poles, in state space (a transfer function's roots lose slow poles' digits)."""
    P = control.ss(G) * (control.ss(control.tf(*control.pade(delay, 12))) if delay else 1)
    loop = control.feedback(P * control.ss(control.tf([kp, ki], [1, 0])), 1)
    return bool(np.all(np.linalg.eigvals(loop.A).real < 0))


def _ki_max(kp: np.ndarray, w: np.ndarray, Gw: np.ndarray, bounds: dict, hi: float) -> np.ndarray:
    """Per proportional gain, the largest ki below the first bound broken: up a log scan of 80 values from
    ``hi * 1e-8`` (where every bound holds) to the first that breaks one, then bisection between (40 steps)."""
    def ok(ki: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Whether each ``(kp[rows], ki)`` meets every bound on the grid (all gains where ``rows`` is None).

        The PI's response kp + ki/(jw) is written as its parts, kp and -ki/w, each rounded once (numpy's complex
        division, five times slower, rounds the imaginary part in two steps; the optima found are the same to the
        last bit for every class here). The largest of 1/|1 + L| is taken as 1 / (the least |1 + L|): the same
        number, IEEE division being monotone."""
        kps = kp if rows is None else kp[rows]
        C = np.empty((kps.size, w.size), complex)
        C.real, C.imag = kps[:, None], -ki[:, None] / w[None, :]
        L = C * Gw[None, :]
        d = np.abs(1 + L)
        good = 1 / np.min(d, axis=1) <= bounds["Ms"]
        if bounds.get("Mt"):
            good &= np.max(np.abs(L) / d, axis=1) <= bounds["Mt"]
        if bounds.get("Mks"):
            good &= np.max(np.abs(C) / d, axis=1) <= bounds["Mks"]
        return good

    scan = np.logspace(np.log10(hi) - 8, np.log10(hi), 80)
    lo, up, open_ = np.zeros(kp.size), np.full(kp.size, hi), np.ones(kp.size, bool)
    for ki in scan:
        if not open_.any():
            break
        # only the gains still below every bound are checked: a closed one's answer is not read
        good = np.zeros(kp.size, bool)
        good[open_] = ok(np.full(int(open_.sum()), ki), open_)
        up = np.where(open_ & ~good, ki, up)
        lo = np.where(open_ & good, ki, lo)
        open_ &= good
    for _ in range(40):
        mid = 0.5 * (lo + up)
        good = ok(mid)
        lo, up = np.where(good, mid, lo), np.where(good, up, mid)
    return lo


def exhaustive_pi(G: control.TransferFunction, delay: float, bounds: dict, kp_range: tuple[float, float],
                  ki_hi: float, data: tuple | None = None) -> tuple[float, float]:
    """The PI of largest ki meeting ``bounds`` with a stable loop (see the module docstring); ``data``: a measured
    response ``(w, G)`` instead of python-control's."""
    w, Gw = data if data is not None else (_grid(G, delay), None)
    if Gw is None:
        Gw = G(1j * w) * np.exp(-1j * w * delay)
    kp = np.logspace(np.log10(kp_range[0]), np.log10(kp_range[1]), 120)
    for _ in range(2):
        ki = _ki_max(kp, w, Gw, bounds, ki_hi)
        ki = np.where([k > 0 and _stable(G, delay, p, 0.999 * k) for p, k in zip(kp, ki)], ki, 0.0)
        i = int(np.argmax(ki))
        kp = np.linspace(kp[max(i - 1, 0)], kp[min(i + 1, kp.size - 1)], 120)
    ki = _ki_max(kp, w, Gw, bounds, ki_hi)
    i = int(np.argmax(ki))
    assert _stable(G, delay, kp[i], 0.999 * ki[i]), "the exhaustive search's optimum is not stable"
    return float(kp[i]), float(ki[i])


def _holds(G: control.TransferFunction, delay: float, r, bounds: dict) -> None:
    """Every bound within the tolerance on the dense grid (python-control's responses), the loop stable."""
    w = _grid(G, delay)
    L = r.controller(1j * w) * G(1j * w) * np.exp(-1j * w * delay)
    d = np.abs(1 + L)
    for name, x in (("Ms", 1 / d), ("Mt", np.abs(L) / d), ("Mks", np.abs(r.controller(1j * w)) / d)):
        if bounds.get(name):
            assert np.max(x) <= bounds[name] * (1 + TOLERANCE), f"{name}: {np.max(x)} over {bounds[name]}"
    assert _stable(G, delay, r.kp, r.ki)


def _two_inertia() -> control.TransferFunction:
    """Motor speed over motor torque, motor and load (1e-3 kg m^2 each) on a shaft of 45 N m/rad, zeta 0.02:
    ``(J_L s^2 + c s + k) / (s (J_M J_L s^2 + (J_M + J_L)(c s + k)))`` (Ellis, Control System Design Guide)."""
    JM = JL = 1e-3
    k = 45.0
    c = 2 * 0.02 * np.sqrt(k * JM * JL / (JM + JL))
    return control.tf([JL, c, k], np.polymul([1.0, 0.0], [JM * JL, (JM + JL) * c, (JM + JL) * k]))


CLASSES = {
    # name: (plant, delay, bounds, the exhaustive search's kp range and ki ceiling)
    "integrating with lag and delay": (1 / (s * (2 * s + 1)), 0.5, {"Ms": 1.4, "Mt": 1.4}, (0.01, 10.0), 10.0),
    "near-integrating (poles three decades apart)": (1 / ((1000 * s + 1) * (s + 1)), 0.1, {"Ms": 1.4, "Mt": 1.4},
                                                     (1.0, 1e4), 1e4),
    "two-inertia drive (a resonance at 300 rad/s)": (_two_inertia(), 0.001, {"Ms": 1.4, "Mt": 1.4, "Mks": 1.0},
                                                     (1e-3, 1.0), 1e3),
    "axial mode (zeta 0.002, narrower than the grid's step)": (
        control.tf([(2 * np.pi * 200) ** 2], np.polymul([1 / (2 * np.pi * 500), 1.0],
                                                      [1.0, 2 * 0.002 * 2 * np.pi * 200, (2 * np.pi * 200) ** 2])),
        2e-4, {"Ms": 1.4, "Mt": 1.4}, (1e-8, 1.0), 1e4),  # its optimum: almost no proportional action
    "oscillatory lag (zeta 0.02)": (4 / ((s + 1) * (s**2 + 0.08 * s + 4)), 0.0, {"Ms": 1.4, "Mt": 1.4},
                                    (1e-7, 10.0), 10.0),  # its optimum: almost no proportional action
    "open-loop unstable": (1 / ((s - 1) * (0.1 * s + 1)), 0.0, {"Ms": 1.6}, (1.0, 50.0), 200.0),
    "delay-dominant": (1 / ((s + 1) * (0.5 * s + 1)), 5.0, {"Ms": 1.4, "Mt": 1.4}, (1e-3, 5.0), 5.0),
    "high order (Skogestad's half-rule example)": (
        (-0.3 * s + 1) * (0.08 * s + 1) / ((2 * s + 1) * (s + 1) * (0.4 * s + 1) * (0.2 * s + 1) * (0.05 * s + 1) ** 3),
        0.0, {"Ms": 1.4, "Mt": 1.4}, (1e-3, 10.0), 10.0),
    "non-minimum phase": ((-2 * s + 1) / ((s + 1) * (0.5 * s + 1) ** 2), 0.0, {"Ms": 1.4, "Mt": 1.4}, (1e-3, 5.0),
                          5.0),
}


QUICK = ("two-inertia drive (a resonance at 300 rad/s)", "axial mode (zeta 0.002, narrower than the grid's step)",
         "open-loop unstable")


@pytest.mark.parametrize("name", [n if n in QUICK else pytest.param(n, marks=pytest.mark.slow) for n in CLASSES])
def test_a_pi_for_each_class_is_the_exhaustive_searchs_optimum(name):
    G, delay, bounds, kp_range, ki_hi = CLASSES[name]
    r = autotune(G, delay_s=delay, form="PI", **bounds)
    kp, ki = exhaustive_pi(G, delay, bounds, kp_range, ki_hi)
    assert r.ki == pytest.approx(ki, rel=2e-3), f"{name}: autotune ki {r.ki}, exhaustive search {ki} (kp {kp})"
    _holds(G, delay, r, bounds)


def test_a_measured_response_with_noise_is_tuned_on_its_data():
    """The FOPDT's response measured at 250 points a decade with 1 % complex noise: the PI the exhaustive search
    finds on the data themselves (the stability from the model the data came from)."""
    G, delay, bounds = 1 / (s + 1) ** 2, 1.0, {"Ms": 1.4, "Mt": 1.4}
    w = np.logspace(-2.5, 2.5, 1251)
    rng = np.random.default_rng(1)
    data = G(1j * w) * np.exp(-1j * w * delay) * (1 + 0.01 * (rng.standard_normal(w.size)
                                                              + 1j * rng.standard_normal(w.size)) / np.sqrt(2))
    r = autotune(control.frd(data, w), form="PI", **bounds)
    kp, ki = exhaustive_pi(G, delay, bounds, (1e-3, 5.0), 5.0, data=(w, data))
    assert r.ki == pytest.approx(ki, rel=2e-3), f"autotune ki {r.ki}, exhaustive search on the data {ki}"
    assert _stable(G, delay, r.kp, r.ki)
