"""
The Pareto front of a catalogue screw
=====================================

The stiffness-drag Pareto front of a catalogue ball screw, with the chosen design marked.

A catalogue screw fixes the nominal diameter, the lead, the ball size and the loaded turns;
what is left to design is the contact angle, the conformity, the balls per turn and the
preloads (the bolts' and the stacks'). The study's design tables are changed to that screw
(HIWIN's R40-10T4-RDI by default: 40 x 10 mm, 6.35 mm balls, 4 turns per nut), the front of
least rigidity against mean drag torque is traced, and the design the study's objective
chooses is marked on it (its rigidity is printed beside the catalogue's at 0.1 C_dyn).

It runs on the default study, the machine axis (``pp.load_study()``, studies/machine_axis.toml: its
feed drive, duty cycle and design limits), unless ``--study`` names another with the design's tables.

Run it from the repository root::

    python examples/pareto_catalogue_screw.py                       # the machine axis, 30 points
    python examples/pareto_catalogue_screw.py --study paper2021 --points 20 --out pareto/
"""

import argparse
from pathlib import Path

from matplotlib.figure import Figure

import piezopreload as pp

#: HIWIN R40-10T4-RDI (ground, double nut): rigidity at 0.1 C_dyn, C_dyn (see docs/references.md)
CATALOGUE = {"name": "R40-10T4-RDI", "nominal_diameter_mm": 40.0, "lead_mm": 10.0, "ball_mm": 6.35, "turns": 4,
             "rigidity_N_per_um": 1010.0, "c_dyn_N": 37890.0}


def front(study: pp.Study, points: int, screw: dict = CATALOGUE) -> pp.DesignResult:
    catalogue = study.replace(
        ballscrew={"nominal_diameter_mm": screw["nominal_diameter_mm"], "lead_mm": screw["lead_mm"],
                   "ball_mm": [screw["ball_mm"], screw["ball_mm"]], "turns": [screw["turns"], screw["turns"]]},
        design={"pareto": ["stiffness:drag"], "pareto_points": points})
    return catalogue.design()


def plot(design: pp.DesignResult, screw: dict = CATALOGUE) -> Figure:
    fig = Figure(figsize=(5.5, 3.8), layout="constrained")
    ax = fig.subplots()
    f = design.fronts[0]
    ax.plot(f.x, f.y, "o-", ms=3, label="Pareto front (each point an optimal design)")
    p = design.optimum.point
    ax.plot([p.stiffness_N_per_um], [p.mean_drag_torque_Nm], "*", ms=14, color="k",
            label=f"chosen: {design.optimum.objective} optimum")
    ax.set(xlabel="least rigidity over the duty cycle (N/um)", ylabel="mean drag torque (N m)",
           title=f"{screw['name']}: {screw['nominal_diameter_mm']:g} x {screw['lead_mm']:g} mm, "
                 f"{screw['ball_mm']:g} mm balls, {screw['turns']} turns")
    ax.legend(fontsize="small")
    return fig


def main(argv: list[str] | None = None) -> pp.DesignResult:
    parser = argparse.ArgumentParser(description="The stiffness-drag Pareto front of a catalogue ball screw, with the "
                                                 "chosen design marked.")
    parser.add_argument("--study", help="a shipped study's name or a study file with the design's tables (default: the "
                                         "machine axis)")
    parser.add_argument("--points", type=int, default=30, help="points on the front")
    parser.add_argument("--out", default="pareto-out", help="folder for the figure and the design artifact")
    args = parser.parse_args(argv)
    study = pp.load_study(args.study)
    design = front(study, args.points)
    out = Path(args.out)
    design.save(out / "design.json", {"study": study.path, "study_sha256": study.sha256})
    plot(design).savefig(out / "pareto.png", dpi=120)
    p = design.optimum.point
    print(f"{CATALOGUE['name']}: {len(design.fronts[0].points)} designs on the front; chosen: contact angle "
          f"{p.contact_angle_deg:.1f} deg, conformity {p.conformity:.3f}, {p.balls_per_turn:.0f} balls per turn, "
          f"rigidity {p.stiffness_N_per_um:.0f} N/um (catalogue {CATALOGUE['rigidity_N_per_um']:.0f} N/um at "
          f"0.1 C_dyn), drag {p.mean_drag_torque_Nm:.3f} N m")
    print(f"wrote {out / 'pareto.png'} and {out / 'design.json'}")
    return design


if __name__ == "__main__":
    main()
