"""The autotuner's plant: a user's linear loop as python-control gives it, with an exact input delay, checked once.

:func:`as_plant` turns a python-control ``TransferFunction`` or ``StateSpace`` (continuous or
discrete; stable, integrating or unstable) or a ``FrequencyResponseData`` (a measured frequency
response), with an input delay ``delay_s``, into a :class:`LinearPlant`: its frequency response
with the delay exact (``e^{-j w L}``, not a Padé approximant), its poles where it has them, its
sign and its integrators, the frequencies that characterise it (the design grid is chosen from
them), and its sampled-data equivalent at a controller's sample period (:meth:`LinearPlant.sampled`:
zero-order hold, the delay split into whole samples and a fraction, exactly). A malformed plant
(not single-input single-output, improper, not finite, a delay that is not a whole number of a
discrete plant's samples, poles on the stability boundary other than integrators) is refused with
an :class:`~piezopreload.core.errors.InputError` that says what was received and what is expected.

:func:`encirclements` and :meth:`LinearPlant.closed_loop_stable` decide the closed loop's
stability: from its poles where the loop is rational, by the Nyquist criterion (the argument of
``1 + L`` along the frequency axis, the integrators indented) where it has a delay or is measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import control
import numpy as np
from scipy.linalg import eigvals as scipy_eigvals
from scipy.linalg import expm

from piezopreload.core.errors import InputError, InternalError

__all__ = ["LinearPlant", "as_plant", "encirclements", "nyquist_unstable"]

_ON_AXIS = 1e-9  # a pole this close to the stability boundary (relative) is on it


def _past_boundary(p: np.ndarray, discrete: bool) -> np.ndarray:
    """The poles' distance past the stability boundary (> 0 unstable): Re p, or |p| - 1 when discrete."""
    return np.abs(p) - 1.0 if discrete else p.real


#: a pole or zero pair damped less than this is a resonance (or an anti-resonance) the grid resolves
LIGHT = 0.3


def _poly(c: Any, what: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(c, float)).ravel()
    if not np.all(np.isfinite(a)):
        raise InputError(f"the plant's {what} coefficients must be finite; {int(np.sum(~np.isfinite(a)))} of "
                         f"{a.size} are not")
    nz = np.flatnonzero(a)
    if nz.size == 0:
        raise InputError(f"the plant's {what} is zero; expected a nonzero polynomial")
    return a[nz[0]:]


def _siso(sys: Any) -> None:
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise InputError(f"the plant must have one input and one output, got {sys.ninputs} inputs and "
                         f"{sys.noutputs} outputs; tune each loop on its own channel (sys[i, j])")


def _sample_period(sys: Any) -> float | None:
    dt = sys.dt
    if dt is None or dt == 0 or dt is False:
        return None
    if dt is True:
        raise InputError("the plant is discrete with an unspecified sample period (dt=True); give it its sample "
                         "period in seconds")
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"the plant's sample period must be a finite number > 0, got {dt!r}")
    return dt


@dataclass(frozen=True, eq=False)
class LinearPlant:
    """A checked linear plant (see the module docstring); built by :func:`as_plant`.

    Parameters
    ----------
    num, den : ndarray or None
        Numerator and denominator, descending powers of ``s`` (or of ``z`` with ``dt``); None for measured data.
    dt : float or None
        The sample period of a discrete plant (s); None for a continuous one.
    delay_s : float
        The input delay (s), exact in the response; a discrete plant's is a whole number of samples.
    omega_data, data : ndarray or None
        A measured response: frequencies (rad/s, increasing) and the complex response there (delay not included).
    source : str
        What it was made from.
    ss : tuple of ndarray or None
        ``(A, B, C, D)`` where the plant was made from a state space (a sampled plant's, its delay a line of
        states): its poles and its simulation come from it.
    hold : _Hold or None
        A sampled plant's zero-order-hold equivalent in its small form: its response comes from it.
    continuous_roots : ndarray or None
        A sampled plant's: the poles and zeros of the continuous plant it was sampled from (its grid is placed
        from them).
    delay_samples : int
        A sampled plant's whole samples of delay, ``z^-N`` in its response (never a polynomial: ``num``, ``den``,
        ``ss`` and ``hold`` are its rational part); a line of states only in :meth:`state_space`, for a time
        response.
    """

    num: np.ndarray | None
    den: np.ndarray | None
    dt: float | None
    delay_s: float
    omega_data: np.ndarray | None = None
    data: np.ndarray | None = None
    source: str = "TransferFunction"
    ss: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    hold: _Hold | None = None
    continuous_roots: np.ndarray | None = None
    delay_samples: int = 0

    # ---- what it is --------------------------------------------------------------------------
    @property
    def rational(self) -> bool:
        return self.num is not None

    @property
    def discrete(self) -> bool:
        return self.dt is not None

    def _tf(self) -> tuple[np.ndarray, np.ndarray]:
        """``(num, den)``, where the caller has found the plant :attr:`rational`."""
        if self.num is None or self.den is None:
            raise InternalError(f"{self.source}: a measured response has no numerator and denominator")
        return self.num, self.den

    def measured_response(self) -> tuple[np.ndarray, np.ndarray]:
        """``(omega_data, data)``, where the caller has found the plant not :attr:`rational`."""
        if self.omega_data is None or self.data is None:
            raise InternalError(f"{self.source}: a rational plant has no measured response")
        return self.omega_data, self.data

    def sample_period(self) -> float:
        """:attr:`dt`, where the caller has found the plant :attr:`discrete`."""
        if self.dt is None:
            raise InternalError(f"{self.source}: a continuous plant has no sample period")
        return self.dt

    @cached_property
    def poles(self) -> np.ndarray | None:
        if self.ss is not None:
            return np.linalg.eigvals(self.ss[0])
        return None if self.den is None else np.roots(self.den)

    @cached_property
    def integrators(self) -> int:
        """Poles at ``s = 0`` (``z = 1``); for measured data, the low-frequency slope of the magnitude in decades,
        fitted by least squares over the lowest half decade (at least three points: one noisy point does not
        decide it)."""
        poles = self.poles
        if poles is None:
            w, data = self.measured_response()
            lw, lg = np.log10(w), np.log10(np.abs(data))
            low = max(3, int(np.searchsorted(lw, lw[0] + 0.5)))
            slope = -np.polyfit(lw[:low], lg[:low], 1)[0]
            return int(np.clip(np.round(slope), 0, 2))
        at = 1.0 if self.discrete else 0.0
        return int(np.sum(np.abs(poles - at) <= _ON_AXIS * max(1.0, np.max(np.abs(poles)))))

    @cached_property
    def unstable_poles(self) -> int:
        """Poles past the stability boundary (measured data: assumed 0, a response measured in open loop)."""
        poles = self.poles
        if poles is None:
            return 0
        return int(np.sum(_past_boundary(poles, self.discrete) > _ON_AXIS))

    @property
    def sign(self) -> float:
        """The sign of the low-frequency gain (``lim s^m G(s)`` for ``m`` integrators): the controller's sign."""
        if self.rational:
            num, den = (np.poly1d(c) for c in self._tf())
            if self.discrete:  # in w = z - 1
                num, den = num(np.poly1d([1.0, 1.0])), den(np.poly1d([1.0, 1.0]))
            return float(np.sign(_lowest(num.coeffs) / _lowest(den.coeffs)))
        # about 0 (type 0) or -90 deg (type 1) when the gain is positive
        phase = np.angle(self.measured_response()[1][0])
        return 1.0 if -0.75 * np.pi < phase <= 0.25 * np.pi else -1.0

    @cached_property
    def roots_s(self) -> np.ndarray:
        """The poles and zeros of the plant's continuous part (rad/s, ``s``-plane; a discrete plant's mapped by
        ``s = ln(z) / dt``; a sampled plant's those of the plant it was sampled from), none at the origin."""
        if self.continuous_roots is not None:
            return self.continuous_roots
        if not self.rational:
            return np.zeros(0, complex)
        num, den = self._tf()
        roots = np.concatenate([np.roots(num), np.roots(den)]).astype(complex)
        if self.discrete:
            roots = np.log(roots[np.abs(roots) > 1e-12]) / self.sample_period()
        return roots[np.abs(roots) > 1e-9 * max(1.0, float(np.max(np.abs(roots), initial=1.0)))]

    def resonances(self) -> np.ndarray:
        """``(w_n, zeta)`` per row of the lightly damped pole and zero pairs (``|zeta| <`` :data:`LIGHT`): a
        resonance or an anti-resonance, stable or not; shape ``(k, 2)``."""
        r = self.roots_s[self.roots_s.imag > 0]
        wn = np.abs(r)
        zeta = -r.real / np.where(wn > 0, wn, 1.0)
        keep = np.abs(zeta) < LIGHT
        return np.column_stack([wn[keep], zeta[keep]])

    def characteristic_frequencies(self) -> np.ndarray:
        """The frequencies (rad/s) of the plant's poles and zeros (not at the origin) and of its delay."""
        if not self.rational:
            omega = self.measured_response()[0]
            return np.array([omega[0], omega[-1]])
        mags = np.abs(self.roots_s)
        delay = self.delay_s + (self.delay_samples * self.sample_period() if self.discrete else 0.0)
        if delay > 0:
            mags = np.append(mags, 1.0 / delay)
        return mags if mags.size else np.array([1.0])

    def grid(self, per_decade: int = 25, widen: float = 0.0, upto: float | None = None) -> np.ndarray:
        """The design grid (rad/s), placed from the plant: log-spaced from a hundredth of its lowest characteristic
        frequency to a hundred times its highest (``widen`` decades more each side), and around each lightly damped
        pole or zero pair ``(w_n, zeta)`` a cluster of ``per_decade`` points over ``w_n e^{+-4 zeta}`` (its peak's
        width is ``2 zeta w_n``: a log grid alone steps over a resonance); a discrete plant's up to just below its
        Nyquist frequency; a measured response's data frequencies (every ``k``-th, for about ``per_decade`` a
        decade). ``upto``: a frequency the grid reaches at least ten times beyond (where the bounds let the loop
        cross over above the plant's own frequencies)."""
        if not self.rational:
            return self._data_grid(per_decade)
        f = self.characteristic_frequencies()
        lo, hi = np.log10(0.01 * f.min()) - widen, np.log10(100.0 * f.max()) + widen
        if upto is not None:
            hi = max(hi, np.log10(10.0 * upto) + widen)
        if self.discrete:
            hi = min(hi, np.log10(0.999 * np.pi / self.sample_period()))
            lo = min(lo, hi - 2.0)
        w = np.logspace(lo, hi, int(np.ceil((hi - lo) * per_decade)) + 1)
        u = np.linspace(-4.0, 4.0, per_decade)
        clusters = [wn * np.exp(max(abs(zeta), 1e-5) * u) for wn, zeta in self.resonances()]
        if clusters:
            w = np.concatenate([w, *clusters])
            w = np.unique(w[(w >= w[0]) & (w <= 10.0**hi)])
        return w

    def _data_grid(self, per_decade: int) -> np.ndarray:
        """A measured response's frequencies, every ``k``-th for about ``per_decade`` a decade, and every one where
        the response turns fast (its phase or log-magnitude moving more than ``1 / k`` per data point: a resonance
        the data resolve and every ``k``-th point would step over)."""
        w, data = self.measured_response()
        decades = np.log10(w[-1] / w[0])
        step = max(1, int(w.size / max(per_decade * decades, 1.0)))
        fast = np.zeros(w.size, bool)
        if step > 1:
            phase, magnitude = np.unwrap(np.angle(data)), np.log(np.abs(data))
            moves = np.maximum(np.abs(np.diff(phase)), np.abs(np.diff(magnitude)))
            fast[:-1] |= moves > 1.0 / step
            fast[1:] |= moves > 1.0 / step
        keep = np.zeros(w.size, bool)
        keep[::step], keep[-1] = True, True
        return w[keep | fast]

    # ---- its response ------------------------------------------------------------------------
    def response(self, omega: Any) -> np.ndarray:
        """``G(j w)`` (``G(e^{j w dt})`` when discrete) at ``omega`` (rad/s), the delay included exactly; a measured
        response between its frequencies by linear interpolation of log-magnitude and unwrapped phase, below them
        its low-frequency asymptote (the lowest point's phase, the magnitude rising with its integrators), above
        them its highest point."""
        w = np.asarray(omega, float)
        delay = np.exp(-1j * w * self.delay_s) if self.delay_s else 1.0  # times 1.0: exactly the same numbers
        if not self.rational:  # below the data: its low-frequency asymptote (its integrators' slope)
            omega, data = self.measured_response()
            lw, lg = np.log(omega), np.log(np.abs(data))
            ph = np.unwrap(np.angle(data))
            x = np.log(np.clip(w, omega[0], omega[-1]))
            below = self.integrators * np.maximum(lw[0] - np.log(np.maximum(w, 1e-300)), 0.0)
            return np.exp(np.interp(x, lw, lg) + below + 1j * np.interp(x, lw, ph)) * delay
        s = np.exp(1j * w * self.sample_period()) if self.discrete else 1j * w
        if self.delay_samples:  # z^-N, as it is
            delay = np.exp(-1j * w * (self.delay_samples * self.sample_period()))
        if self.hold is not None:
            return self.hold.response(s) * delay
        num, den = self._tf()
        return np.polyval(num, s) / np.polyval(den, s) * delay

    def transfer_function(self) -> control.TransferFunction:
        """The rational part as a python-control transfer function (the delay is :attr:`delay_s`, a discrete plant's
        :attr:`delay_samples`)."""
        if not self.rational:
            raise InputError("a measured frequency response has no transfer function; fit one (fit_plant)")
        return control.tf(self.num, self.den, 0 if self.dt is None else self.dt)

    # ---- sampled ---------------------------------------------------------------------------------
    def sampled(self, Ts: float) -> LinearPlant:
        """The plant between a controller's D/A (zero-order hold) and A/D at sample period ``Ts``: exact for a
        rational plant (the delay split into whole samples and a fraction, Åström and Wittenmark's modified
        z-transform); for measured data, ``G(j w) (1 - e^{-j w Ts}) / (j w Ts)`` below the Nyquist frequency
        (the hold's response at the fundamental; the aliases are left out)."""
        if not (np.isfinite(Ts) and Ts > 0):
            raise InputError(f"the sample period must be a finite number > 0, got {Ts!r}")
        if self.dt is not None:
            if abs(Ts - self.dt) > 1e-9 * self.dt:
                raise InputError(f"the plant is discrete with sample period {self.dt:g} s; the controller's must be "
                                 f"the same, got {Ts:g} s")
            return self
        if not self.rational:
            omega, data = self.measured_response()
            w = omega[omega < np.pi / Ts]
            if w.size < 4:
                raise InputError(f"the measured response has {w.size} frequencies below the Nyquist frequency of "
                                 f"Ts = {Ts:g} s; expected at least 4")
            hold = np.where(w * Ts > 0, (1 - np.exp(-1j * w * Ts)) / (1j * w * Ts), 1.0)
            return LinearPlant(None, None, Ts, self.delay_s, w, data[:w.size] * hold,
                               f"{self.source}, held at {Ts:g} s")
        whole = int(np.floor(self.delay_s / Ts + 1e-9))  # z^-whole: a factor of the response, not states
        ss, zoh = _sampled_ss(*self._tf(), max(self.delay_s - whole * Ts, 0.0), Ts)
        tf = control.ss2tf(*ss, Ts)
        num, den = _trim(tf.num[0][0]), _trim(tf.den[0][0])
        return LinearPlant(_poly(num, "numerator"), _poly(den, "denominator"), Ts, 0.0,
                           source=f"{self.source}, held at {Ts:g} s", ss=ss, hold=zoh,
                           continuous_roots=self.roots_s, delay_samples=whole)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C, D)`` of a discrete rational plant, its delay as a line of states."""
        if not (self.rational and self.discrete):
            raise InputError("a state space is taken of a discrete rational plant; sample it first (sampled(Ts))")
        A, B, C, D = self.rational_state_space()
        return _delayed(A, B, C, D, self.delay_samples) if self.delay_samples else (A, B, C, D)

    def rational_state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C, D)`` of a discrete rational plant without its whole samples of delay (:attr:`delay_samples`:
        a simulation shifts its input by them)."""
        if not (self.rational and self.discrete):
            raise InputError("a state space is taken of a discrete rational plant; sample it first (sampled(Ts))")
        if self.ss is not None:
            return self.ss
        sys = control.tf2ss(*self._tf(), self.dt)
        return np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C), np.asarray(sys.D)

    # ---- the closed loop -----------------------------------------------------------------------
    def closed_loop_stable(self, controller: Any) -> bool:
        """Whether the loop with ``controller`` is stable: from the closed loop's poles where plant and controller
        are rational and the plant has no delay, else by the Nyquist criterion (:func:`nyquist_unstable`) on a
        grid that resolves the phase of ``1 + L``. ``controller`` gives ``num_den(dt)`` (None where it has no
        rational form), ``response(omega, dt)`` and ``integrators``."""
        exact = self.rational and self.delay_s == 0.0 and self.delay_samples == 0
        rational = controller.num_den(self.dt) if exact else None
        if rational is not None:
            return bool(np.all(_past_boundary(self._closed_loop_eigenvalues(*rational), self.discrete) < -_ON_AXIS))
        omega, loop = self.resolved_loop(lambda w: controller.response(w, self.dt))
        return nyquist_unstable(omega, loop, self.unstable_poles, self.integrators + controller.integrators,
                                self.dt) == 0

    @cached_property
    def _realisation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C, D)`` of a rational plant: its own state space, or python-control's realisation of its transfer
        function (made once: every closed-loop check of the plant uses it)."""
        if self.ss is not None:
            return self.ss
        return _matrices(control.tf2ss(*self._tf(), 0 if self.dt is None else self.dt))

    def _closed_loop_eigenvalues(self, c_num: np.ndarray, c_den: np.ndarray) -> np.ndarray:
        """The eigenvalues of the loop's state matrix (plant and controller in state space, negative feedback):
        better conditioned than the roots of the characteristic polynomial for long delay lines."""
        dt = 0 if self.dt is None else self.dt
        A, B, C, D = self._realisation
        Ac, Bc, Cc, Dc = _matrices(control.tf2ss(c_num, c_den, dt))
        # u = Cc xc + Dc e, e = -y, y = C x + D u: y = (C x + D Cc xc) / (1 + D Dc)
        k = 1.0 / (1.0 + float(D[0, 0]) * float(Dc[0, 0]))
        y_x, y_xc = k * C, k * float(D[0, 0]) * Cc
        u_x, u_xc = -float(Dc[0, 0]) * y_x, Cc - float(Dc[0, 0]) * y_xc
        top = np.hstack([A + B @ u_x, B @ u_xc])
        bottom = np.hstack([-Bc @ y_x, Ac - Bc @ y_xc])
        return np.linalg.eigvals(np.vstack([top, bottom]))

    def resolved_loop(self, controller_response: Any) -> tuple[np.ndarray, np.ndarray]:
        """The loop ``C G`` on a grid fine enough for the Nyquist criterion: the plant's grid a decade wider, ten
        times denser, points added where ``1 + L`` turns by more than an eighth of a turn between neighbours; a
        continuous loop's grid extended until ``|L| < 1/2``, a discrete loop's ending at its Nyquist frequency; an
        integrating loop's extended down until ``|L| >= 10`` (where the criterion's indentation holds).
        Measured data: its own frequencies (the phase must be resolved there; checked), below them the asymptote."""
        def loop_at(w: np.ndarray) -> np.ndarray:
            return np.asarray(controller_response(w), complex) * self.response(w)

        start = self.measured_response()[0] if not self.rational else self.grid(per_decade=250, widen=1.0)
        w = _down_to_asymptote(start, loop_at)
        if not self.rational:
            return w, loop_at(w)
        if self.discrete:
            w = np.append(w[w < np.pi / self.sample_period()], np.pi / self.sample_period())
        else:
            for _ in range(12):
                if abs(loop_at(w[-1:])[0]) < 0.5:
                    break
                w = np.append(w, np.logspace(np.log10(w[-1]), np.log10(w[-1]) + 1.0, 251)[1:])
        loop = loop_at(w)
        for _ in range(8):
            turn = np.abs(np.angle((1.0 + loop[1:]) * np.conj(1.0 + loop[:-1])))
            # where |L| < 1/2 at both ends 1 + L stays in the right half plane (|L| is smooth on the grid: the
            # delay turns only its phase), so it cannot circle the origin there however fast the delay turns it
            near = np.maximum(np.abs(loop[1:]), np.abs(loop[:-1])) >= 0.5
            coarse = np.flatnonzero((turn > np.pi / 4) & near)
            if coarse.size == 0:
                break
            mid = np.sqrt(w[coarse] * w[coarse + 1])
            w = np.insert(w, coarse + 1, mid)
            loop = np.insert(loop, coarse + 1, loop_at(mid))
        return w, loop


def _down_to_asymptote(w: np.ndarray, loop_at: Any) -> np.ndarray:
    """``w`` extended down, a decade at a time (at most twelve), while the loop's gain still grows below it and is
    under 10: an integrating loop's grid reaches its asymptote, where the Nyquist criterion's indentation holds."""
    for _ in range(12):
        ends = np.abs(loop_at(np.array([w[0] / 10.0, w[0]])))
        if ends[1] >= 10.0 or ends[0] < 1.5 * ends[1]:
            break
        w = np.concatenate([np.logspace(np.log10(w[0]) - 1.0, np.log10(w[0]), 26)[:-1], w])
    return w


def _delayed(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, N: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, D)`` with ``N`` samples of input delay as a line of states (``u[k-1] .. u[k-N]``)."""
    n = A.shape[0]
    Ad, Bd = np.zeros((n + N, n + N)), np.zeros((n + N, 1))
    Ad[:n, :n], Ad[:n, n + N - 1:] = A, B
    Bd[n, 0] = 1.0
    for i in range(1, N):
        Ad[n + i, n + i - 1] = 1.0
    Cd = np.hstack([C, np.zeros((1, N))])
    Cd[0, n + N - 1] += float(D[0, 0])
    return Ad, Bd, Cd, np.zeros((1, 1))


def _matrices(sys: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return tuple(np.atleast_2d(np.asarray(m, float))  # type: ignore[return-value]
                 for m in (sys.A, sys.B, sys.C, sys.D))


def _trim(c: Any) -> np.ndarray:
    """A polynomial's coefficients without leading ones that are rounding noise (below 1e-12 of the largest)."""
    a = np.asarray(c, float).ravel()
    big = np.flatnonzero(np.abs(a) > 1e-12 * float(np.max(np.abs(a), initial=0.0)))
    return a[big[0]:] if big.size else a


def _lowest(coeffs: np.ndarray) -> float:
    """The lowest-order nonzero coefficient of a polynomial given in descending powers."""
    ascending = np.asarray(coeffs, float)[::-1]
    scale = float(np.max(np.abs(ascending)))
    return float(ascending[np.flatnonzero(np.abs(ascending) > 1e-12 * scale)[0]])


@dataclass(frozen=True, eq=False)
class _Hold:
    """A zero-order-hold equivalent in its small form: ``P(z) = z^-d C (zI - Phi)^-1 (G0 + G1 z^-1) + D z^-dd``."""

    Phi: np.ndarray
    G0: np.ndarray
    G1: np.ndarray
    C: np.ndarray
    D: float
    d: int
    d_direct: int

    def response(self, z: np.ndarray) -> np.ndarray:
        eye = np.eye(self.Phi.shape[0])
        rhs = self.G0[None] + self.G1[None] / z[:, None, None]
        x = np.linalg.solve(z[:, None, None] * eye[None] - self.Phi[None], rhs)
        return (self.C @ x)[:, 0, 0] * z ** (-self.d) + self.D * z ** (-self.d_direct)


def _sampled_ss(num: np.ndarray, den: np.ndarray, delay_s: float, Ts: float
                ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], _Hold]:
    """The zero-order-hold equivalent of ``num/den e^{-s L}`` at ``Ts``: with ``L = d Ts + tau`` (``0 <= tau < Ts``),
    ``x+ = Phi x + G0 u[k-d] + G1 u[k-d-1]``, ``G0 = int_0^{Ts-tau} e^{As} ds B``,
    ``G1 = e^{A(Ts-tau)} int_0^tau e^{As} ds B``; the delayed inputs are states."""
    sys = control.tf2ss(num, den)
    A, B, C, D = (np.atleast_2d(np.asarray(m, float)) for m in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    d = int(np.floor(delay_s / Ts + 1e-9))
    tau = max(delay_s - d * Ts, 0.0)
    if tau < 1e-9 * Ts:
        tau = 0.0

    def integral(t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(e^{A t}, int_0^t e^{As} ds B)``."""
        M = expm(np.block([[A, B], [np.zeros((1, n + 1))]]) * t)
        return M[:n, :n], M[:n, n:]

    Phi, _ = integral(Ts)
    E, G0 = integral(Ts - tau)
    _, Gt = integral(tau)
    G1 = E @ Gt
    if tau > 0 and np.any(D != 0):
        d_direct = d + 1
    else:
        d_direct = d
    lags = max(d + (1 if tau > 0 else 0), d_direct)
    # states: x, then u[k-1], ..., u[k-lags]
    N = n + lags
    Ad, Bd = np.zeros((N, N)), np.zeros((N, 1))
    Ad[:n, :n] = Phi

    def feed(lag: int, gain: np.ndarray) -> None:  # x+ += gain u[k - lag]
        if lag == 0:
            Bd[:n] += gain
        else:
            Ad[:n, n + lag - 1:n + lag] += gain

    feed(d, G0)
    if tau > 0:
        feed(d + 1, G1)
    if lags:
        Bd[n, 0] = 1.0
        for i in range(1, lags):
            Ad[n + i, n + i - 1] = 1.0
    Cd, Dd = np.zeros((1, N)), np.zeros((1, 1))
    Cd[:, :n] = C
    if d_direct == 0:
        Dd[:] = D
    else:
        Cd[0, n + d_direct - 1] += float(D[0, 0])
    hold = _Hold(Phi, G0, G1 if tau > 0 else np.zeros_like(G0), C, float(D[0, 0]), d, d_direct)
    return (Ad, Bd, Cd, Dd), hold


def as_plant(plant: Any, delay_s: float = 0.0) -> LinearPlant:
    """A python-control ``TransferFunction``, ``StateSpace`` or ``FrequencyResponseData`` (or a :class:`LinearPlant`)
    with an input delay, checked (see the module docstring)."""
    if not (isinstance(delay_s, int | float) and np.isfinite(delay_s) and delay_s >= 0):
        raise InputError(f"delay_s must be a finite number >= 0, got {delay_s!r}")
    delay_s = float(delay_s)
    if isinstance(plant, LinearPlant):
        return plant if delay_s == 0 else LinearPlant(plant.num, plant.den, plant.dt, plant.delay_s + delay_s,
                                                      plant.omega_data, plant.data, plant.source, plant.ss, plant.hold,
                                                      plant.continuous_roots, plant.delay_samples)
    if isinstance(plant, control.FrequencyResponseData):
        return _from_frd(plant, delay_s)
    if isinstance(plant, control.StateSpace | control.TransferFunction):
        _siso(plant)
        tf = _ss_to_tf(plant) if isinstance(plant, control.StateSpace) else plant
        return _from_tf(tf, delay_s, type(plant).__name__)
    raise InputError(f"the plant must be a python-control TransferFunction, StateSpace or FrequencyResponseData, "
                     f"got {type(plant).__name__}")


def _ss_to_tf(sys: control.StateSpace) -> control.TransferFunction:
    """A state space's transfer function from its poles (the eigenvalues of ``A``), its zeros (the finite
    generalised eigenvalues of the system pencil ``[[A, B], [C, D]]``) and its gain at a frequency away from both:
    no coefficient of rounding noise. (The characteristic-polynomial route leaves ones of 1e-15 where a coefficient
    is zero, and they make zeros at 1e14 rad/s and integrators at -1e-14 rad/s that the grid then reaches for.) A root
    within a billionth of the largest of the origin is at the origin."""
    A, B, C, D = (np.atleast_2d(np.asarray(m, float)) for m in (sys.A, sys.B, sys.C, sys.D))
    if not all(np.all(np.isfinite(m)) for m in (A, B, C, D)):
        raise InputError("the plant's state-space matrices must be finite")
    n = A.shape[0]
    dt = _sample_period(sys)
    if n == 0:
        return control.tf([float(D[0, 0])], [1.0], 0 if dt is None else dt)
    poles = np.linalg.eigvals(A)
    scale = max(1.0, float(np.max(np.abs(poles))))
    pencil = np.block([[A, B], [C, D]])
    E = np.zeros((n + 1, n + 1))
    E[:n, :n] = np.eye(n)
    with np.errstate(all="ignore"):
        z = scipy_eigvals(pencil, E)
    zeros = z[np.isfinite(z) & (np.abs(z) < 1e8 * scale)]

    def snap(r: np.ndarray) -> np.ndarray:
        at = 1.0 if dt is not None else 0.0
        r = np.where(np.abs(r - at) <= _ON_AXIS * scale, at, r)
        return np.where(np.abs(r.imag) <= _ON_AXIS * scale, r.real, r)

    poles, zeros = snap(poles), snap(zeros)
    roots = np.concatenate([poles, zeros])
    mags = np.abs(roots[np.abs(roots) > 0])
    w0 = float(np.exp(np.mean(np.log(mags)))) if mags.size else 1.0
    for s0 in (1j * w0 * f for f in (1.0, 0.37, 2.9, 0.11, 7.3)):  # a frequency on no root
        x0 = np.exp(s0 * dt) if dt is not None else s0
        gain = (C @ np.linalg.solve(x0 * np.eye(n) - A, B))[0, 0] + D[0, 0]
        shape = np.prod(x0 - zeros) / np.prod(x0 - poles)
        if np.isfinite(gain) and abs(shape) > 0 and np.isfinite(shape):
            break
    k = float(np.real(gain / shape))
    if k == 0.0 or not np.isfinite(k):
        raise InputError("the plant's transfer function is zero (its input does not reach its output)")
    return control.tf(k * np.real(np.poly(zeros)) if zeros.size else np.array([k]), np.real(np.poly(poles)),
                      0 if dt is None else dt)


def _from_tf(tf: control.TransferFunction, delay_s: float, source: str) -> LinearPlant:
    dt = _sample_period(tf)
    num, den = _poly(tf.num[0][0], "numerator"), _poly(tf.den[0][0], "denominator")
    if num.size > den.size:
        raise InputError(f"the plant is improper (numerator degree {num.size - 1} > denominator degree "
                         f"{den.size - 1}); a physical plant's gain falls at high frequency")
    whole = 0
    if dt is not None:  # the delay as z^-k in the response (never as k poles at the origin)
        k = delay_s / dt
        if abs(k - round(k)) > 1e-9 * max(1.0, k):
            raise InputError(f"a discrete plant's delay must be a whole number of its samples ({dt:g} s), got "
                             f"{delay_s:g} s ({k:.6g} samples)")
        whole, delay_s = int(round(k)), 0.0
    plant = LinearPlant(num, den, dt, delay_s, source=source, delay_samples=whole)
    poles = np.roots(den)  # plant.poles: it has no state space
    scale = max(1.0, float(np.max(np.abs(poles), initial=1.0)))
    near = np.abs(_past_boundary(poles, plant.discrete)) <= _ON_AXIS * scale
    at = 1.0 if dt is not None else 0.0
    odd = poles[near & (np.abs(poles - at) > _ON_AXIS)]
    if odd.size:
        raise InputError(f"the plant has poles on the stability boundary ({', '.join(f'{p:.4g}' for p in odd)}) "
                         "other than integrators; the autotuner needs them off it (add a little damping)")
    return plant


def _from_frd(frd: control.FrequencyResponseData, delay_s: float) -> LinearPlant:
    _siso(frd)
    omega = np.asarray(frd.omega, float)
    data = np.asarray(frd.eval(omega), complex).ravel()
    if omega.size < 8:
        raise InputError(f"a measured frequency response needs at least 8 frequencies, got {omega.size}")
    if not (np.all(np.isfinite(omega)) and np.all(omega > 0) and np.all(np.diff(omega) > 0)):
        raise InputError("the measured response's frequencies must be finite, > 0 and strictly increasing")
    if not np.all(np.isfinite(data)) or np.any(data == 0):
        raise InputError("the measured response must be finite and nonzero at every frequency")
    dt = _sample_period(frd)
    return LinearPlant(None, None, dt, delay_s, omega, data, "FrequencyResponseData")


def encirclements(omega: np.ndarray, loop: np.ndarray, integrators: int, dt: float | None) -> float:
    """The counterclockwise turns of ``1 + L`` about the origin as the frequency runs over the whole axis
    (``-w..w``, the Nyquist contour: up the imaginary axis, or around the unit circle), the ``integrators`` poles at
    ``s = 0`` (``z = 1``) indented on the unstable side, and the high-frequency end closed (``|L| < 1`` there: the
    loop falls off; a discrete loop is real at the Nyquist frequency)."""
    f = 1.0 + np.asarray(loop, complex)
    phase = np.unwrap(np.angle(f))
    half = phase[-1] - phase[0]
    if dt is None:  # from the grid's end to infinity 1 + L stays in the right half plane (|L| < 1): back to 0
        half += -np.angle(f[-1])
    return (2.0 * half - integrators * np.pi) / (2.0 * np.pi)


def nyquist_unstable(omega: np.ndarray, loop: np.ndarray, open_loop_unstable: int, integrators: int,
                     dt: float | None) -> int:
    """The closed loop's unstable poles by the Nyquist criterion, ``Z = P - N`` with ``N`` the counterclockwise
    turns of :func:`encirclements`. ``omega`` must resolve the phase of ``1 + L`` (adjacent points turn less than
    half a turn) and end where ``|L| < 1`` (continuous) or at the Nyquist frequency; an
    :class:`~piezopreload.core.errors.InputError` says when it does not."""
    loop = np.asarray(loop, complex)
    if dt is None and abs(loop[-1]) >= 1.0:
        raise InputError(f"the loop's gain is {abs(loop[-1]):.3g} >= 1 at the grid's highest frequency "
                         f"({omega[-1]:.4g} rad/s): the frequencies must reach beyond the loop's crossover")
    turns = encirclements(omega, loop, integrators, dt)
    return int(round(open_loop_unstable - turns))
