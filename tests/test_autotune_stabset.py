"""The stabilising-set slices' two closed forms against independent computations: each line's gaps of ``ki``
(:func:`~piezopreload.tuning.stabset.line_gaps`) against a dense scan of ``ki`` through the discs, and the Nyquist
count (:func:`~piezopreload.tuning.stabset.unstable_counts`) against python-control's closed-loop poles."""

from __future__ import annotations

import control
import numpy as np

from piezopreload.tuning.stabset import line_gaps, unstable_counts


def _scanned_gaps(alpha: np.ndarray, b: np.ndarray, r2: np.ndarray, forbidden: np.ndarray,
                  ki: np.ndarray) -> list[tuple[float, float]]:
    """The runs of ``ki`` on the scan where the line meets every disc: outside each forbidden one, inside each allowed
    one (``|alpha + ki b|^2`` against the radius squared)."""
    dist = np.abs(alpha[None, :] + ki[:, None] * b[None, :]) ** 2
    ok = np.all(np.where(forbidden[None, :], dist >= r2[None, :], dist <= r2[None, :]), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
    return [(float(ki[s]), float(ki[e - 1])) for s, e in zip(edges[::2], edges[1::2])]


def test_line_gaps_are_the_gaps_a_dense_scan_of_ki_finds():
    """On random discs and lines, the three highest gaps (and the lowest, where there are more) are the runs a scan of
    100,000 points of ``(0, cap]`` finds, to the scan's step; runs shorter than ten steps are left out of both."""
    rng = np.random.default_rng(7)
    cap, n = 4.0, 100_000
    ki = np.linspace(0.0, cap, n + 1)[1:]
    step = ki[1] - ki[0]
    checked, many = 0, 0
    for trial in range(60):
        rows = int(rng.integers(3, 14))
        b = rng.standard_normal(rows) + 1j * rng.standard_normal(rows)
        r2 = rng.uniform(0.2, 2.5, rows) ** 2
        forbidden = rng.uniform(size=rows) < 0.85
        alpha = rng.standard_normal((5, rows)) + 1j * rng.standard_normal((5, rows))
        if trial % 2:  # lines that cross each disc near its own ki: many gaps between them
            r2 = rng.uniform(0.05, 0.3, rows) ** 2
            alpha = -rng.uniform(0.0, cap, (5, rows)) * b + 0.5 * np.sqrt(r2) * rng.standard_normal((5, rows))
        gaps = line_gaps(alpha, b[None, :], r2, forbidden, cap)
        for line in range(5):
            runs = [r for r in _scanned_gaps(alpha[line], b, r2, forbidden, ki) if r[1] - r[0] > 10 * step]
            got = [tuple(g) for g in gaps[line] if np.isfinite(g[0]) and g[1] - g[0] > 10 * step]
            expect = sorted(runs, key=lambda r: -r[1])[:3] + (runs[:1] if len(runs) >= 4 else [])
            assert len(got) == len(expect), (got, expect)
            for (lo, hi), (slo, shi) in zip(got, expect):
                assert abs(lo - slo) <= 2 * step and abs(hi - shi) <= 2 * step, ((lo, hi), (slo, shi))
            checked, many = checked + len(expect), many + (len(runs) >= 4)
    assert checked > 50 and many > 0  # the lines do cross the discs, some into four gaps or more (the lowest kept)


def test_unstable_counts_match_the_closed_loop_poles():
    """For PI controllers on ``e^0 / (s + 1)^3`` and on the unstable ``1 / ((s - 1)(0.2 s + 1))``, the count of
    unstable closed-loop poles from the Nyquist criterion (every loop at once) is python-control's."""
    rng = np.random.default_rng(3)
    w = np.logspace(-6, 4, 4000)
    s = 1j * w
    plants = (([1.0], np.poly([-1.0, -1.0, -1.0]), 0), ([1.0], np.polymul([1.0, -1.0], [0.2, 1.0]), 1))
    for num, den, unstable in plants:
        gains = np.exp(rng.uniform(np.log(0.05), np.log(20.0), (40, 2)))
        G = np.polyval(num, s) / np.polyval(den, s)
        L = (gains[:, :1] + gains[:, 1:] / s[None, :]) * G[None, :]
        counts = unstable_counts(L, unstable, 1, None)
        plant = control.tf(num, den)
        expected = [int(np.sum(control.feedback(control.tf([kp, ki], [1.0, 0.0]) * plant).poles().real > 0))
                    for kp, ki in gains]
        assert counts.tolist() == expected
        assert 0 < sum(c == 0 for c in expected) < len(expected)  # both stable and unstable loops among them
