"""The co-design's two fronts (artifacts/codesign.py) and the report's co-design section (reports/codesign.py).

``front_dominates`` is checked against an independent formulation: the multiplicative epsilon indicator of
Zitzler et al. (IEEE Trans. Evol. Comput. 7(2):117-132, 2003, doi:10.1109/TEVC.2003.810758), the least factor by
which the co-designed front must be scaled to weakly dominate every sequential point; "nowhere worse" is that factor
at most 1 (within the tolerance). The benchmark's former verdict took the co-designed front as the non-dominated set
of the sequential points and the co-design's, so it held by construction; the cases below where it must not hold
would have passed it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from piezopreload.artifacts.codesign import FRONT_RTOL, CodesignRecord, FrontPoint, RequirementRow, nondominated
from piezopreload.core.errors import ArtifactError


def _p(growth: float, tracking: float, *, ms: float = 1.6, feasible: bool = True, label: str = "p") -> FrontPoint:
    return FrontPoint(label, 0.0, growth, tracking, ms, 100.0, 1000.0, 55.0, feasible, 0.2, "" if feasible else "x")


def _record(seq: list[FrontPoint], co: list[FrontPoint], ms_max: float = 1.6) -> CodesignRecord:
    rows = (RequirementRow("least rigidity over the duty", "N/um", "min", 1773.0, 813.0, 300.0),
            RequirementRow("Monte Carlo worst peak_voltage_V", "V", "max", 110.6, 103.4, 110.0),
            RequirementRow("nominal tracking RMS, whole range", "N", "max", 27.6, 25.2, 40.0),
            RequirementRow("thermal growth over the shift, duty-cycle estimate", "um", "max", 43.7, 7.4, None))
    return CodesignRecord("axis", "nested", "nested, not simultaneous: the tuning exposes no sensitivities",
                          {"growth": 1.0, "friction": 0.0, "tracking": 1.0, "voltage": 0.0}, ms_max, 0.54,
                          ("stiffness_N_per_um 1773 -> 813 N/um",), "growth: the nut's drag heat", "one robust set",
                          rows, 3, tuple(seq), tuple(co), False, True)


def _epsilon_indicator(co: list[tuple[float, float]], seq: list[tuple[float, float]]) -> float:
    """Zitzler's multiplicative epsilon indicator I(co, seq): max over seq of min over co of max_i co_i / seq_i."""
    a, b = np.asarray(co, float), np.asarray(seq, float)
    return float(np.max(np.min(np.max(a[:, None, :] / b[None, :, :], axis=2), axis=0)))


def test_front_dominates_is_the_epsilon_indicator_at_most_one_on_random_fronts():
    rng = np.random.default_rng(41)
    seen = {True: 0, False: 0}
    for _ in range(300):
        seq = [_p(*x) for x in rng.uniform(5.0, 50.0, (rng.integers(1, 6), 2))]
        co = [_p(*x) for x in rng.uniform(5.0, 50.0, (rng.integers(1, 6), 2))]
        r = _record(seq, co)
        expected = _epsilon_indicator([q.at() for q in co], [p.at() for p in seq]) <= 1.0 + FRONT_RTOL
        assert r.front_dominates() == expected, f"{[p.at() for p in seq]} against {[q.at() for q in co]}"
        seen[expected] += 1
    assert seen[True] > 10 and seen[False] > 10, f"the draws did not exercise both verdicts: {seen}"


def test_a_co_designed_front_worse_somewhere_does_not_dominate():
    # the sequential sweep reaches 7.4 um at 25.2 N; the co-designed sweep's answers stop at 8.8 um: worse in growth
    # there, though better in tracking elsewhere. The former benchmark (the co-designed front taken as the
    # non-dominated set of both sweeps) called this true.
    seq = [_p(7.37, 25.22), _p(43.7, 27.62)]
    co = [_p(8.80, 25.10), _p(14.6, 24.9)]
    r = _record(seq, co)
    assert not r.front_dominates()
    union = nondominated(seq + co)
    assert all(any(q.growth_um <= p.growth_um and q.tracking_rms_N <= p.tracking_rms_N for q in union) for p in seq)
    assert r.strictly_dominated() == 1  # (8.8, 25.1) beats (43.7, 27.6) in both


def test_the_fronts_are_compared_at_the_study_s_ms_and_among_feasible_pairs_only():
    seq = [_p(10.0, 30.0)]
    # a co-designed pair better in both, but tuned above the study's Ms: it does not count
    assert not _record(seq, [_p(5.0, 20.0, ms=1.7)]).front_dominates()
    # nor does one that misses the co-design's constraints
    assert not _record(seq, [_p(5.0, 20.0, feasible=False)]).front_dominates()
    # at the Ms limit (within the tolerance) it does
    assert _record(seq, [_p(5.0, 20.0, ms=1.6 * (1 + 0.5 * FRONT_RTOL))]).front_dominates()
    # a sequential pair above the Ms limit is not a point of the front at the study's Ms
    assert _record([_p(1.0, 1.0, ms=2.0), _p(10.0, 30.0)], [_p(9.0, 29.0)]).front_dominates()
    # equal within the tolerance is no worse
    assert _record(seq, [_p(10.0 * (1 + 0.5 * FRONT_RTOL), 30.0)]).front_dominates()
    assert not _record(seq, [_p(10.0 * (1 + 2 * FRONT_RTOL), 30.0)]).front_dominates()
    # an empty co-designed front dominates nothing
    assert not _record(seq, []).front_dominates()


def test_nondominated_keeps_exactly_the_points_no_other_beats():
    rng = np.random.default_rng(7)
    for _ in range(100):
        pts = [_p(*x) for x in rng.uniform(1.0, 10.0, (8, 2))]
        kept = {p.at() for p in nondominated(pts, rtol=0.0)}
        brute = {p.at() for p in pts if not any(q.growth_um <= p.growth_um and q.tracking_rms_N <= p.tracking_rms_N
                                                 and q.at() != p.at() for q in pts)}
        assert kept == brute
    # a single point dominating the rest: the front is that point
    assert [p.at() for p in nondominated([_p(7.4, 25.2), _p(8.8, 25.2), _p(43.7, 27.6)])] == [(7.4, 25.2)]


def test_the_codesign_artifact_reads_back_what_it_wrote(tmp_path):
    r = _record([_p(7.37, 25.22), _p(43.7, 27.62)], [_p(7.37, 25.22)])
    path = r.save(tmp_path / "codesign.json")
    back = CodesignRecord.load(path)
    assert back == r
    doc = json.loads(path.read_text())
    assert doc["schema"] == "piezopreload/codesign/1"
    del doc["codesigned_front"][0]["growth_um"]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match=r"codesigned_front\[0\]\.growth_um"):
        CodesignRecord.load(tmp_path / "bad.json")


def test_the_report_section_says_what_the_fronts_show():
    pytest.importorskip("matplotlib")
    from piezopreload.reports.codesign import codesign_section

    one = _record([_p(7.37, 25.22), _p(43.7, 27.62)], [_p(7.37, 25.22), _p(7.37, 25.22)])
    part = codesign_section(one)
    text = " ".join(part.section.paragraphs)
    assert "nowhere worse than the sequential one at the same Ms" in text
    assert "single point" in text and "weak" in text
    assert [name for name, _, _ in part.figures] == ["codesign-fronts"]
    requirement_rows = part.section.tables[0].rows
    assert requirement_rows[0][0] == "least rigidity over the duty (N/um)"
    assert requirement_rows[0][2].endswith("(met)") and requirement_rows[3][1] == "-"
    assert requirement_rows[1][2].endswith("(missed)") and requirement_rows[1][3].endswith("(met)")
    assert "Monte Carlo worst peak_voltage_V 110.6 to 103.4 V, now met" in text
    assert "3 Monte Carlo plants: the sequential answer failed, the co-designed one passed" in text
    # what it moved, in the requirements' units (the rigidity 1,773 to 813 N/um, still above its 300 N/um)
    assert "least rigidity over the duty 1,773 to 813 N/um" in text
    assert "nominal tracking RMS, whole range 27.6 to 25.2 N" in text and "now" not in text.split("moved")[1][:60]

    worse = codesign_section(_record([_p(7.37, 25.22), _p(43.7, 27.62)], [_p(8.8, 25.1), _p(14.6, 24.9)]))
    text = " ".join(worse.section.paragraphs)
    assert "worse than the sequential one somewhere" in text and "single point" not in text

    none = codesign_section(_record([], []))
    assert not none.figures and "[thermal]" in none.section.omitted[0]
