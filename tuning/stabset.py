"""Where the autotuner starts: the stabilising set of the ``(kp, ki)`` plane cut by the bounds (D-decomposition).

With the derivative gain and the filter's time constant ``(kd, Tf)`` held, the controller is affine in its
proportional and integral gains, ``C = kp a(w) + ki b(w) + c(w)`` (``a``, ``b``, ``c`` the responses of ``kp = 1``,
``ki = 1``, ``kd``: every form and loop of :func:`~piezopreload.tuning.pidform.controller_response`). At each grid
frequency each bound is a disc in the plane of ``C``, with ``G`` the plant's response there:

* ``|S| <= Ms``: ``|C + 1/G| >= 1/(Ms |G|)``, outside the disc about ``-1/G``;
* ``|T| <= Mt`` (``Mt > 1``): ``L = C G`` outside the disc about ``-Mt^2/(Mt^2 - 1)`` of radius ``Mt/(Mt^2 - 1)``;
* ``|KS| <= Mks``: ``|C| <= k |C - p|`` with ``p = -1/G``, ``k = Mks |G|``: Apollonius' circle about
  ``k^2 p / (k^2 - 1)`` of radius ``k |p| / |k^2 - 1|``, forbidden inside where ``k > 1``, allowed inside where
  ``k < 1``.

Under ``(kp, ki) -> C`` each disc is an ellipse, and on a line ``kp = const`` an interval of ``ki`` whose ends are
the roots of a quadratic: the gains that meet every bound on the grid are, on each line, a few intervals (gaps
between the forbidden intervals, inside the allowed ones), in closed form (:func:`line_gaps`). The closed loop's
poles cross the stability boundary only where ``L(jw) = -1`` (the centre of the ``|S|`` disc, inside it) or at
``s = 0`` (``ki = 0``): Neimark's D-decomposition, which Silva, Datta and Bhattacharyya (2005, *PID Controllers for
Time-Delay Systems*) apply to PI and PID with delay; Åström, Panagopoulos and Hägglund (1998) draw the ``|S|``
ellipses the same way for the MIGO designs. So each gap keeps one stability verdict, decided once by the Nyquist
criterion inside it (near its top, where on the grid ``|1 + L| >= 1/Ms``: the count is well resolved), and the top
of the highest stabilising gap is the line's largest integral gain.

:func:`slice_optima` maximises it over ``kp`` on a batch of ``(kd, Tf)`` slices at once (a log grid of ``kp``,
then finer grids about each slice's best); :func:`stabilising_starts` runs the PI slice and, for a PID, a 3 x 3
grid of slices about the PI's scales (:func:`_pid_slices`: the derivative's high-frequency gain ``kd / Tf``
against the PI's ``kp`` and the bound on ``|KS|``, ``Tf`` against the PI's integral time), and returns the best
slice of each regime as starts for the local solve. The result holds on the design grid; the local solve and the
dense check take it from there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from piezopreload.tuning.loopshape import Bound
from piezopreload.tuning.pidform import PIDController, controller_response

__all__ = ["SliceOptimum", "Plane", "plane_of", "bound_discs", "line_gaps", "unstable_counts", "slice_optima",
           "stabilising_starts", "stabilising_any", "RELAX"]

#: the proportional gains a slice searches: per decade; the PID slices' decades about the PI's (the PI's are
#: relative to ``1/|G|`` at the reference frequency: four decades below, three above)
_KP_PER_DECADE = 5
_PID_KP = (-4.0, 1.5)
#: the largest integral gain a line reports, relative to ``1/|G|`` times the reference frequency (no bound met
#: before); far above it an integral action's phase lag leaves only unstable loops
_KI_CAP = 1e3
#: the fractions of the highest frequency where ``Mks |G| >= 1`` about which a PID's slices are searched too, by
#: filter order: the first order's optima lie about a third of it (a near-integrating plant, a two-inertia plant
#: measured on its motor), the second order's on a plant measured on its load (the filter rolls the controller off
#: at the resonance) a decade below it too; each fraction costs a batch of slices, so the first order's one
_REACH = {1: (3.0,), 2: (3.0, 10.0)}
#: the gaps of each slice whose stability is checked at once, best first
_CHECK = 4


@dataclass(frozen=True)
class SliceOptimum:
    """The best line of a slice ``(kd, Tf)``: ``kp`` and its largest stabilising ``ki``; ``capped`` where no bound
    stopped ``ki`` (the search's cap did)."""

    kp: float
    ki: float
    kd: float
    Tf: float
    capped: bool

    def controller(self, filter_order: int, dt: float | None, shrink: float = 1e-3) -> PIDController:
        """The slice's controller, its ``ki`` a fraction ``shrink`` inside the first bound (a feasible start)."""
        return PIDController(self.kp, self.ki * (1.0 - shrink), self.kd, self.Tf if self.kd else 0.0,
                             filter_order, dt)


def bound_discs(G: np.ndarray, bounds: dict[str, float | None]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bound given and frequency (stacked by bound): the disc's centre in the plane of ``C``, its radius squared,
    and whether its inside is forbidden (else allowed); see the module docstring."""
    G = np.asarray(G, complex)
    aG = np.abs(G)
    p = -1.0 / G
    centres, radii2, forbidden = [], [], []
    if bounds.get(Bound.MS) is not None:
        centres.append(p)
        radii2.append((1.0 / (bounds[Bound.MS] * aG)) ** 2)
        forbidden.append(np.ones(G.size, bool))
    mt = bounds.get(Bound.MT)
    if mt is not None:
        m2 = max(float(mt), 1.0 + 1e-6) ** 2  # Mt = 1: the half plane Re L >= -1/2, as a large disc
        centres.append(-m2 / (m2 - 1.0) / G)
        radii2.append((np.sqrt(m2) / (m2 - 1.0) / aG) ** 2)
        forbidden.append(np.ones(G.size, bool))
    if bounds.get(Bound.MKS) is not None:
        k = bounds[Bound.MKS] * aG
        k = np.where(np.abs(k - 1.0) < 1e-9, 1.0 + 1e-9, k)  # k = 1: a half plane, as a large disc
        k2 = k * k
        centres.append(k2 * p / (k2 - 1.0))
        radii2.append((k * np.abs(p) / (k2 - 1.0)) ** 2)
        forbidden.append(k > 1.0)
    return np.concatenate(centres), np.concatenate(radii2), np.concatenate(forbidden)


def line_gaps(alpha: np.ndarray, b: np.ndarray, r2: np.ndarray, forbidden: np.ndarray, cap: float,
              most: int = 4) -> np.ndarray:
    """The ``most - 1`` highest intervals of ``ki`` in ``(0, cap]`` that meet every bound on the grid, per line (the
    leading axes of ``alpha``), ``(lo, hi)`` by ``hi`` descending, and the lowest one (NaN where a line has fewer):
    outside every forbidden disc's interval, inside every allowed one's. ``alpha`` is ``C`` at ``ki = 0`` less the
    discs' centres, ``b`` the integral gain's response (both per row of the discs, the last axis). Shape
    ``(..., most, 2)``."""
    A = b.real**2 + b.imag**2
    B = 2.0 * (alpha.real * b.real + alpha.imag * b.imag)
    C = alpha.real**2 + alpha.imag**2 - r2
    disc = B * B - 4.0 * A * C
    root = np.sqrt(np.maximum(disc, 0.0))
    minus_B, two_A = -B, 2.0 * A
    lo, hi = (minus_B - root) / two_A, (minus_B + root) / two_A
    meets = disc > 0.0
    f = np.broadcast_to(forbidden, lo.shape)
    # the allowed discs' intervals intersect in one interval, with (0, cap]
    a_lo = np.maximum(np.where(~f, lo, 0.0).max(axis=-1), 0.0)
    a_hi = np.minimum(np.where(~f, hi, np.inf).min(axis=-1), cap)
    a_hi = np.where(np.any(~f & ~meets, axis=-1), -np.inf, a_hi)
    # the forbidden intervals' union: with their lower ends and their upper ends each sorted, the k-th gap (k of the
    # intervals below it) lies between the k-th upper end and the (k+1)-th lower end where the one is below the
    # other; the last, above them all, from the largest upper end
    hit = f & meets
    f_lo = np.sort(np.where(hit, lo, np.inf), axis=-1)
    f_hi = np.sort(np.where(hit, hi, np.inf), axis=-1)
    lead, n = alpha.shape[:-1], f_lo.shape[-1]
    starts, ends = np.empty((*lead, n + 1)), np.empty((*lead, n + 1))
    starts[..., 0], starts[..., 1:n], starts[..., n] = -np.inf, f_hi[..., :-1], np.where(hit, hi, -np.inf).max(axis=-1)
    ends[..., :n], ends[..., n] = f_lo, np.inf
    s_, e_ = np.maximum(starts, a_lo[..., None]), np.minimum(ends, a_hi[..., None])
    valid = e_ > s_
    valid[..., :-1] &= np.isfinite(ends[..., :-1])  # the sweep's end: only the last slot
    # the gaps lie in the order of their slots: the highest are the last valid ones, the lowest the first
    flat = valid.reshape(-1, n + 1)
    line, slot = np.nonzero(flat)  # by line, then slot
    total = flat.sum(axis=-1)
    first = np.cumsum(total) - total  # each line's first in (line, slot)
    rank = total[line] - 1 - (np.arange(line.size) - first[line])  # the valid slots above it
    out = np.full((flat.shape[0], most, 2), np.nan)
    gaps = np.stack([s_.reshape(-1, n + 1)[line, slot], e_.reshape(-1, n + 1)[line, slot]], axis=-1)
    high = rank < most - 1
    out[line[high], rank[high]] = gaps[high]
    low = (rank == total[line] - 1) & (total[line] >= most)  # the lowest, where it is not among the highest
    out[line[low], most - 1] = gaps[low]
    out = out.reshape(*lead, most, 2)
    return out


def unstable_counts(L: np.ndarray, unstable: int, integrators: int, dt: float | None) -> np.ndarray:
    """The closed loop's unstable poles by the Nyquist criterion for each row of ``L`` (a loop on the grid, its
    controller's integrator among ``integrators``); a large number where a continuous loop's gain is not below 1 at
    the grid's end (the count cannot be closed there). Vectorised :func:`~piezopreload.tuning.lti.nyquist_unstable`."""
    f = 1.0 + L
    # the phase's change over the grid: the sum of its steps, each the principal angle of the ratio of neighbours
    # (what unwrapping the phase adds up, without building the unwrapped phase)
    half = np.angle(f[..., 1:] * np.conj(f[..., :-1])).sum(axis=-1)
    closed = np.ones(L.shape[:-1], bool)
    if dt is None:
        half = half - np.angle(f[..., -1])
        closed = np.abs(L[..., -1]) < 1.0
    turns = (2.0 * half - integrators * np.pi) / (2.0 * np.pi)
    return np.where(closed, np.round(unstable - turns), 10**6).astype(int)


@dataclass(frozen=True)
class Plane:
    """What every slice shares: the design grid and the plant's response there, the bounds' discs, the grid the
    Nyquist count runs on (``count_w``, ``count_G``: the design grid, or every measured point, with eight decades
    below it, where an integrating loop's gain grows to its asymptote), the plant's unstable poles and integrators,
    the controller's form and sample period, the bound on ``|KS|`` (None: none)."""

    omega: np.ndarray
    G: np.ndarray
    discs: tuple[np.ndarray, np.ndarray, np.ndarray]
    count_w: np.ndarray
    count_G: np.ndarray
    unstable: int
    integrators: int
    filter_order: int
    dt: float | None
    Mks: float | None = None

    def basis(self, w: np.ndarray, kd: np.ndarray, Tf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``a``, ``b``, ``c`` of the slices ``(kd, Tf)`` at ``w``: shape ``(slices, w.size)``."""
        order = self.filter_order
        kd, Tf = np.asarray(kd, float)[:, None], np.asarray(Tf, float)[:, None]

        def resp(kp: float, ki: float, d: np.ndarray) -> np.ndarray:
            re, im = controller_response(kp, ki, d, Tf, w[None, :], order, self.dt)
            return np.broadcast_to(np.asarray(re) + 1j * np.asarray(im), (kd.shape[0], w.size))

        return resp(1.0, 0.0, 0.0 * kd), resp(0.0, 1.0, 0.0 * kd), resp(0.0, 0.0, kd)


def plane_of(omega: np.ndarray, G: np.ndarray, count_w: np.ndarray, count_G: np.ndarray,
             bounds: dict[str, float | None], unstable: int, integrators: int, filter_order: int,
             dt: float | None) -> Plane:
    """The :class:`Plane` of the grid ``omega`` (``G`` there) with the Nyquist count's grid ``count_w``."""
    return Plane(omega, G, bound_discs(G, bounds), count_w, count_G, unstable, integrators, filter_order, dt,
                 bounds.get(Bound.MKS))


def _tops(plane: Plane, kp: np.ndarray, basis: tuple[np.ndarray, ...], count: tuple[np.ndarray, ...],
          cap: float) -> np.ndarray:
    """Per slice and line ``kp`` (shape ``(slices, lines)``), the top of its highest stabilising gap (``-inf``:
    none). The gaps are checked by the Nyquist criterion nine tenths of the way up, best first, :data:`_CHECK` of
    each slice at a time until each slice's best stabilising gap is known."""
    a, b, c = basis
    centre, r2, forbidden = plane.discs
    alpha = kp[..., None] * a[:, None, :] + (c[:, None, :] - centre)
    gaps = line_gaps(alpha, b[:, None, :], r2, forbidden, cap)  # (S, m, 3, 2)
    S, m = kp.shape
    lo, hi = gaps[..., 0].reshape(S, -1), gaps[..., 1].reshape(S, -1)
    order = np.argsort(-np.where(np.isfinite(hi), hi, -np.inf), axis=1)
    best = np.full(S, -np.inf)
    where = np.full(S, -1)
    ca, cb, cc = count
    for k in range(0, order.shape[1], _CHECK):
        idx = order[:, k:k + _CHECK]
        h = np.take_along_axis(hi, idx, axis=1)
        todo = np.isfinite(h) & ~np.isfinite(best)[:, None]
        if not todo.any():
            break
        s, j = np.nonzero(todo)
        flat = idx[s, j]
        line = flat // gaps.shape[2]
        ki = lo[s, flat] + 0.9 * (hi[s, flat] - lo[s, flat])
        L = (kp[s, line][:, None] * ca[s] + ki[:, None] * cb[s] + cc[s]) * plane.count_G[None, :]
        ok = unstable_counts(L, plane.unstable, plane.integrators + 1, plane.dt) == 0
        for q in np.flatnonzero(ok):  # the first stable gap of each slice in the order checked (best first)
            if not np.isfinite(best[s[q]]):
                best[s[q]], where[s[q]] = hi[s[q], flat[q]], line[q]
    tops = np.full((S, m), -np.inf)
    found = where >= 0
    tops[np.flatnonzero(found), where[found]] = best[found]
    return tops


def slice_optima(plane: Plane, kd: np.ndarray, Tf: np.ndarray, kp_ref: float, w_ref: float,
                 kp_decades: tuple[float, float] = (-4.0, 3.0)) -> list[SliceOptimum | None]:
    """The largest stabilising ``ki`` that meets the bounds on each slice ``(kd[i], Tf[i])`` (None: no line has
    one). ``kp`` on a log grid about ``kp_ref`` (``kp_decades`` each side), then two finer grids about each slice's
    best."""
    kd, Tf = np.atleast_1d(np.asarray(kd, float)), np.atleast_1d(np.asarray(Tf, float))
    rows = plane.discs[0].size // plane.omega.size
    a, b, c = plane.basis(plane.omega, kd, Tf)
    basis = (np.tile(a, rows), np.tile(b, rows), np.tile(c, rows))
    count = plane.basis(plane.count_w, kd, Tf)
    cap = _KI_CAP * kp_ref * w_ref
    n = int((kp_decades[1] - kp_decades[0]) * _KP_PER_DECADE) + 1
    kp = np.broadcast_to(kp_ref * np.logspace(*kp_decades, n), (kd.size, n))
    tops = _tops(plane, kp, basis, count, cap)
    i = np.argmax(tops, axis=1)
    rows_ = np.arange(kd.size)
    best_kp, best_ki = kp[rows_, i].copy(), tops[rows_, i].copy()
    lo, hi = kp[rows_, np.maximum(i - 1, 0)], kp[rows_, np.minimum(i + 1, n - 1)]
    for _ in range(2):  # finer grids about each slice's best
        fine = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, 7)[None, :]
        t = _tops(plane, fine, basis, count, cap)
        j = np.argmax(t, axis=1)
        better = t[rows_, j] > best_ki
        best_kp = np.where(better, fine[rows_, j], best_kp)
        best_ki = np.where(better, t[rows_, j], best_ki)
        lo, hi = fine[rows_, np.maximum(j - 1, 0)], fine[rows_, np.minimum(j + 1, 6)]
    return [SliceOptimum(float(best_kp[q]), float(best_ki[q]), float(kd[q]), float(Tf[q]),
                         bool(best_ki[q] >= cap * (1 - 1e-12))) if np.isfinite(best_ki[q]) else None
            for q in range(kd.size)]


def _references(omega: np.ndarray, G: np.ndarray, hints: tuple[float, ...] = ()) -> list[tuple[float, float]]:
    """Reference frequencies and ``1/|G|`` there, the scales the slices search about: the first phase crossover of
    ``G`` where its phase starts above -170 degrees (else the frequency where ``|G|`` is the geometric middle of its
    range on the grid), then each of ``hints`` (the plant's characteristic frequencies and a fifth of the lowest: a
    plant whose phase starts at -180 degrees, a double integrator, is controlled below its first resonance or pole;
    an unstable one about its unstable pole) more than a factor 3 from those before it."""
    phase = np.unwrap(np.angle(G))
    phase -= 2 * np.pi * np.round(phase[0] / (2 * np.pi))
    below = np.flatnonzero(phase <= -np.pi)
    if below.size and phase[0] > -np.radians(170.0):
        i = int(below[0])
    else:
        lg = np.log(np.abs(G))
        i = int(np.argmin(np.abs(lg - 0.5 * (lg.max() + lg.min()))))
    picked = [i]
    for w in hints:
        j = int(np.argmin(np.abs(np.log(omega / w))))
        if all(abs(np.log(omega[j] / omega[k])) > np.log(3.0) for k in picked):
            picked.append(j)
    return [(float(omega[k]), float(1.0 / np.abs(G[k]))) for k in picked]


def _pid_slices(plane: Plane, pi: SliceOptimum | None, w_ref: float, kp_ref: float,
                Tf_min: float) -> list[list[tuple[str, SliceOptimum]]]:
    """The PID's slices, by rows of ``Tf``: the derivative's high-frequency gain ``g = kd / Tf`` and ``Tf`` about the
    PI's ``kp`` (``k1``) and integral time (``t1``): ``g`` of ``1.5 k1``, ``6 k1`` and, with a bound on ``|KS|``, what
    it leaves beside ``1.5 k1`` of proportional gain (``|C(inf)| = kp + g``); ``Tf`` of ``0.07``, ``0.2`` and ``2``
    times ``t1``. Where no PI stabilises (a double integrator, an unstable plant behind a delay), ``k1`` and ``t1``
    are the reference's ``1/|G|`` and period and ``g`` is ``0.3 k1`` or ``3 k1``. The optima of the benchmark
    batch's reference lie in these regimes: ``|KS|`` on its bound with a fast filter, an intermediate one, and
    (delay-dominant plants) almost no proportional gain and a slow filter, the derivative a lagged proportional
    action."""
    k1 = pi.kp if pi is not None else kp_ref
    t1 = pi.kp / pi.ki if pi is not None and not pi.capped else 1.0 / w_ref
    gains = [1.5 * k1, 6.0 * k1] if pi is not None else [0.3 * k1, 3.0 * k1]  # no PI: a PD's lead about the reference
    if plane.Mks is not None:
        gains = [g for g in gains if g < plane.Mks - 0.5 * k1] + ([plane.Mks - 1.5 * k1] if plane.Mks > 2 * k1 else
                                                                  [0.5 * plane.Mks])
    else:
        gains.append(25.0 * k1)
    times = np.maximum(np.array((0.07, 0.2, 2.0) if pi is not None else (0.1, 0.5, 2.0)) * t1, Tf_min)
    Tf = np.repeat(times, len(gains))  # every slice in one batch, row by row
    opts = slice_optima(plane, np.tile(gains, times.size) * Tf, Tf, k1, 1.0 / t1, kp_decades=_PID_KP)
    return [[(f"slice kd {o.kd:.3g}, Tf {o.Tf:.3g} s", o) for o in opts[r * len(gains):(r + 1) * len(gains)]
             if o is not None] for r in range(times.size)]


def _pi_slice(plane: Plane, refs: list[tuple[float, float]]) -> tuple[tuple[float, float], SliceOptimum] | None:
    """The PI slice's optimum about the first reference; about the next only where it finds none."""
    for ref in refs:
        pi = slice_optima(plane, np.zeros(1), np.zeros(1), ref[1], ref[0])[0]
        if pi is not None:
            return ref, pi
    return None


def _reach_references(plane: Plane, pi: SliceOptimum | None) -> list[tuple[float, float]]:
    """Where a PID may cross over far above the PI's loop: the fractions :data:`_REACH` of the highest grid frequency
    where ``Mks |G| >= 1`` (above it ``|KS|``, about ``|C| >= 1/|G|`` at a crossover, would break its bound) and
    ``1/|G|`` there; none without ``Mks`` or where that frequency is the grid's end, and not one within a decade of
    the PI's own scale ``ki/kp`` (the PI's slices cover it). A plant whose phase falls to -180 degrees above a slow
    pole (a near-integrating one, a double integrator with a resonance) has its PI confined decades below the
    frequencies a PID's lead reaches: slices about the PI alone never see them."""
    if plane.Mks is None:
        return []
    above = np.flatnonzero(plane.Mks * np.abs(plane.G) >= 1.0)
    if above.size == 0 or above[-1] >= plane.omega.size - 1:
        return []
    out = []
    for w in plane.omega[above[-1]] / np.array(_REACH[plane.filter_order]):
        if pi is not None and not pi.capped and w < 10.0 * pi.ki / pi.kp:
            continue
        j = int(np.argmin(np.abs(np.log(plane.omega / w))))
        out.append((float(plane.omega[j]), float(1.0 / np.abs(plane.G[j]))))
    return out


def _distinct(found: list[tuple[str, SliceOptimum]], plane: Plane,
              keep: int) -> list[tuple[str, PIDController, SliceOptimum]]:
    """The first ``keep`` of ``found`` more than 10 % apart from those before in ``kp``, ``kd`` or ``Tf``."""
    out: list[tuple[str, PIDController, SliceOptimum]] = []
    for name, opt in found:
        if all(abs(np.log(opt.kp / o.kp)) > 0.1 or abs(np.log((opt.kd + 1e-300) / (o.kd + 1e-300))) > 0.1
               or abs(np.log((opt.Tf + 1e-300) / (o.Tf + 1e-300))) > 0.1 for _, _, o in out):
            out.append((name, opt.controller(plane.filter_order, plane.dt), opt))
        if len(out) == keep:
            break
    return out


def stabilising_starts(plane: Plane, Tf_min: float = 0.0, keep: int = 3,
                       hints: tuple[float, ...] = ()) -> list[tuple[str, PIDController, SliceOptimum]]:
    """Starts ``(name, controller, slice)``, best first: for a PI its slice's optimum; for a PID the best slice of
    each row of :func:`_pid_slices` (each a regime of its own, so the local solves start in each basin), then the
    PI's, at most ``keep`` distinct ones. The PI slice about the first reference of :func:`_references` (about the
    next where it finds none), the PID's about the PI's optimum, or, where no PI stabilises, about each reference.
    Empty where no slice has a stabilising line that meets the bounds on the grid."""
    refs = _references(plane.omega, plane.G, hints)
    got = _pi_slice(plane, refs)
    pi = None if got is None else got[1]
    found: list[tuple[str, SliceOptimum]] = []
    if plane.filter_order > 0:
        for w_ref, kp_ref in ([got[0]] if got is not None else refs):
            for row in _pid_slices(plane, pi, w_ref, kp_ref, Tf_min):
                if row:
                    found.append(max(row, key=lambda nf: nf[1].ki))
        for reach in _reach_references(plane, pi):
            for row in _pid_slices(plane, None, *reach, Tf_min):
                if row:
                    found.append(max(row, key=lambda nf: nf[1].ki))
        found.sort(key=lambda nf: -nf[1].ki)
    if pi is not None:
        found.append(("PI slice", pi))
    return _distinct(found, plane, keep)


#: the factors :func:`stabilising_any` relaxes the bounds by, in turn
RELAX = (1.5, 2.0, 3.0, 5.0, 10.0, 100.0)


def stabilising_any(plane: Plane, bounds: dict[str, float | None], Tf_min: float = 0.0,
                    hints: tuple[float, ...] = (),
                    factors: tuple[float, ...] = RELAX) -> list[tuple[str, PIDController, SliceOptimum]]:
    """Starts for the least-violation problem of bounds no controller meets: the bounds relaxed by ``factors`` in
    turn until a slice has a stabilising line that meets them."""
    for factor in factors:
        relaxed = {k: (None if m is None else m * factor) for k, m in bounds.items()}
        starts = stabilising_starts(replace(plane, discs=bound_discs(plane.G, relaxed), Mks=relaxed.get(Bound.MKS)),
                                    Tf_min, keep=2, hints=hints)
        if starts:
            return starts
    return []
