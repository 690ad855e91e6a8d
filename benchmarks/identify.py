"""Identification speed: the whole P-I identification against scipy's NNLS on precomputed operators.

100,000 samples, 40 play operators. "Ours" is `PIIdentifier.fit`: the play operators from the
raw input, the Gram compression, the cvxpy/Clarabel QP and the active-set polish. The peer is
`scipy.optimize.nnls` given the operator outputs already computed (offset as two nonnegative
columns), so the ratio charges ours for work the peer is spared. Median of several repeats.
The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import time

import numpy as np
from scipy.optimize import nnls

from piezopreload.models.hysteresis import ClassicalPI, play, uniform_thresholds
from piezopreload.tuning.identify import PIIdentifier

N_SAMPLES, N_OPERATORS, REPEATS = 100_000, 40, 5


def timed(fn) -> tuple[float, object]:
    times, result = [], None
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), result


def main() -> dict[str, float]:
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 10.0, N_SAMPLES)
    v = 100.0 * np.sin(2 * np.pi * t) * (1.0 - 0.09 * t)  # a 1 Hz sine decaying from 100 V
    r = uniform_thresholds(N_OPERATORS, 100.0)
    w = rng.uniform(0.001, 0.02, N_OPERATORS)
    w[0] = 0.1
    y = ClassicalPI(r, w, 2.0)(v) + rng.normal(0.0, 0.05, N_SAMPLES)

    ours_s, est = timed(lambda: PIIdentifier(thresholds=r).fit(v, y))
    ops = play(v, r)
    phi = np.column_stack([ops, np.ones(N_SAMPLES), -np.ones(N_SAMPLES)])
    nnls_s, (x, _) = timed(lambda: nnls(phi, y))
    operators_s, _ = timed(lambda: play(v, r))
    agree = float(np.max(np.abs(est.model_.weights - x[:N_OPERATORS])) / np.max(np.abs(x[:N_OPERATORS])))
    result = {
        "samples": N_SAMPLES,
        "operators": N_OPERATORS,
        "identify_s": ours_s,
        "play_operators_s": operators_s,
        "qp_solve_s": est.solve_time_s_,
        "nnls_s": nnls_s,
        "identify_vs_nnls_ratio": ours_s / nnls_s,
        "weights_max_rel_diff": agree,
    }
    print(f"identification of {N_OPERATORS} weights from {N_SAMPLES} samples: ours {1e3 * ours_s:.1f} ms "
          f"(operators {1e3 * operators_s:.1f} ms), scipy nnls on precomputed operators {1e3 * nnls_s:.1f} ms, "
          f"ratio {ours_s / nnls_s:.2f}; weights agree to {agree:.1e}")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
