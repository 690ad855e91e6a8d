"""The report's co-design section: the sequential answer against the co-designed one, and their two fronts.

From the co-design artifact (:class:`~piezopreload.artifacts.codesign.CodesignRecord`, written by the design stage
of a study whose design step is the co-design): how it was solved and why, what it changed and what that bought,
each requirement sequential against co-designed in its unit, and one figure of the two fronts of thermal growth
against tracking RMS at the study's Ms, with the verdict of :meth:`CodesignRecord.front_dominates` as computed from
them.
"""

from __future__ import annotations

from matplotlib.figure import Figure

from piezopreload.artifacts.codesign import CodesignRecord, FrontPoint, nondominated
from piezopreload.reports.document import ReportTable, Section, fmt
from piezopreload.reports.figures import COLOURS, legends, page_figure, styled
from piezopreload.reports.sections import Part

__all__ = ["codesign_section", "codesign_fronts_figure"]

_FRONT_COLOURS = {"sequential": COLOURS["study pid"], "co-designed": COLOURS["tuned ff+pid"]}


def _verdict(row_met: bool | None) -> str:
    return "" if row_met is None else (" (met)" if row_met else " (missed)")


def _cell(x: float, unit: str) -> str:
    return fmt(x, 4, unit)


@styled
def codesign_fronts_figure(r: CodesignRecord) -> Figure:
    """Thermal growth against tracking RMS: every point of each sweep (open), each front's non-dominated points
    joined (filled), the two answers marked."""
    fig, ax = page_figure(2.8)
    a = ax[0][0]
    # the sequential front's markers larger, so a co-designed point on top of one leaves it visible
    for name, points, marker, size in (("sequential", r.sequential_front, "o", 7.0),
                                       ("co-designed", r.codesigned_front, "s", 3.5)):
        colour = _FRONT_COLOURS[name]
        swept = [p for p in points if p.feasible]
        a.plot([p.growth_um for p in swept], [p.tracking_rms_N for p in swept], marker, mfc="none", ms=size + 3,
               color=colour, label=f"{name} sweep ({len(swept)} points)")
        front = nondominated(points)
        a.plot([p.growth_um for p in front], [p.tracking_rms_N for p in front], marker + "-", ms=size, color=colour,
               label=f"{name} front")
    a.set_xlabel("thermal growth over the shift, duty-cycle estimate (um)")
    a.set_ylabel("nominal tracking RMS along the preload schedule (N)")
    a.set_title(f"both at Ms <= {fmt(r.ms_max)}")
    legends(a)
    return fig


def _point_row(which: str, p: FrontPoint) -> tuple[str, ...]:
    return (which, p.label, _cell(p.stiffness_N_per_um, "N/um"), _cell(p.growth_um, "um"),
            _cell(p.tracking_rms_N, "N"), fmt(p.ms, 4), "yes" if p.feasible else f"no: {p.why}")


def codesign_section(r: CodesignRecord) -> Part:
    """The co-design section: the answers requirement by requirement, and the two fronts where they were swept.

    Parameters
    ----------
    r : CodesignRecord
        The design stage's co-design artifact.

    Returns
    -------
    Part
        The section and its figure.
    """
    changed = "; ".join(r.changed) if r.changed else "nothing: the sequential design is kept"
    paragraphs = [
        f"The design was chosen with its controller by a {r.strategy} co-design ({r.strategy_why}). "
        f"Its objective weighs {', '.join(f'{k} {fmt(w)}' for k, w in r.weights.items() if w > 0)} (each over the "
        f"sequential answer's value); the co-designed answer's objective is {fmt(r.objective_ratio, 4)} of the "
        f"sequential one's.",
        f"What it changed in the design: {changed}. Of the controller: {r.controller}. What bought the difference: "
        f"{r.coupling}.",
    ]
    moved = []
    for row in r.requirements:
        if abs(row.codesigned - row.sequential) <= 1e-3 * max(abs(row.sequential), 1e-12):
            continue
        flip = ""
        if row.met("sequential") is not None and row.met("sequential") != row.met("codesigned"):
            flip = ", now met" if row.met("codesigned") else ", now missed"
        moved.append(f"{row.requirement} {_cell(row.sequential, row.unit)} to {_cell(row.codesigned, row.unit)}"
                     f"{' ' + row.unit if row.unit else ''}{flip}")
    paragraphs.append("In the requirements' units, the co-design moved " + "; ".join(moved) + "." if moved else
                      "The co-design moved no requirement's figure: it kept the sequential answer.")
    if r.plants:
        verdict = {True: "passed", False: "failed", None: "was not run"}
        paragraphs.append(f"Both answers ran through the same {r.plants} Monte Carlo plants: the sequential answer "
                          f"{verdict[r.passed_sequential]}, the co-designed one {verdict[r.passed_codesigned]}.")
    rows = tuple((row.requirement + (f" ({row.unit})" if row.unit else ""),
                  "-" if row.limit is None else f"{row.kind.words} {fmt(row.limit, 4)}",
                  _cell(row.sequential, row.unit) + _verdict(row.met("sequential")),
                  _cell(row.codesigned, row.unit) + _verdict(row.met("codesigned")))
                 for row in r.requirements)
    tables = [ReportTable(("requirement", "limit", "sequential", "co-designed"), rows,
                    "Each requirement, the sequential answer against the co-designed one, in its unit.", "lrrr")]
    figures: tuple[tuple[str, Figure, str], ...] = ()
    omitted: list[str] = []
    if r.sequential_front and r.codesigned_front:
        dominates, strictly = r.front_dominates(), r.strictly_dominated()
        seq_front, co_front = nondominated(r.sequential_front), nondominated(r.codesigned_front)
        paragraphs.append(
            f"The two fronts of thermal growth against tracking RMS along the preload schedule, every pair tuned at "
            f"Ms <= {fmt(r.ms_max)}: the "
            f"sequential sweep is the design alone along its least-heat front ({len(r.sequential_front)} designs, "
            f"each then tuned), the co-designed sweep the co-design at {len(r.codesigned_front)} weights of the "
            f"growth against the tracking. Their non-dominated points: {len(seq_front)} sequential, {len(co_front)} "
            f"co-designed. The co-designed front is "
            + ("nowhere worse than the sequential one at the same Ms" if dominates else
               "worse than the sequential one somewhere at the same Ms (a sequential point no co-designed point "
               "matches in both growth and tracking)")
            + f"; it beats {strictly} of the {len(r.sequential_front)} sequential points in both."
            + (" Each front's non-dominated set is a single point: along these sweeps the growth and the tracking do "
               "not trade against each other (the design that grows least also tracks best), so the coupling "
               "between the design and the controller is weak here." if len(seq_front) == 1 and len(co_front) == 1
               else ""))
        tables.append(ReportTable(("front", "swept", "rigidity", "growth", "tracking RMS", "Ms", "feasible"),
                            tuple(_point_row("sequential", p) for p in r.sequential_front)
                            + tuple(_point_row("co-designed", p) for p in r.codesigned_front),
                            "The fronts' sweeps: each design-and-controller pair, at the study's Ms.", "llrrrrl",
                            small=True))
        figures = (("codesign-fronts", codesign_fronts_figure(r),
                    f"Thermal growth against tracking RMS at Ms <= {fmt(r.ms_max)}: the sequential and the "
                    f"co-designed sweeps and fronts."),)
    else:
        omitted.append("the fronts of thermal growth against tracking: the study has no [thermal] table (the shift "
                       "the growth is read over)")
    section = Section("Co-design: the preload system and its controller chosen together", tuple(paragraphs),
                      tuple(tables), tuple(name for name, _, _ in figures), tuple(omitted))
    return Part(section, figures)
