"""Study files (TOML): what a study runs on, validated on load.

A study names the rig (the simulated plant's parameters), the controller's gains, the
feedforward's identification experiment, the references and the simulation settings. Every
key is checked: an unknown key, a wrong type or an out-of-range value is an
:class:`~piezopreload.io.InputError` naming the file, the line and the key's path.

The paper's study, ``paper2021.toml``, ships with the package (:func:`default_study`).
"""

from __future__ import annotations

import hashlib
import math
import re
import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from piezopreload.core.errors import InputError
from piezopreload.core.tables import read_input
from piezopreload.models.actuator import P888_91, RigParams, StackData
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import PIDGains
from piezopreload.tuning.calibrate import LoopExcitation
from piezopreload.tuning.pid import TuningSpec
from piezopreload.tuning.validate import Criteria

__all__ = ["Study", "StudyText", "RigRunPlan", "load_study", "read_study_text", "default_study", "DEFAULT_STUDY",
           "EXPORT_FORMATS"]

DEFAULT_STUDY = "paper2021.toml"

_NUM = (int, float)
_RIG_SCALARS = {f.name for f in fields(RigParams)} - {"stack", "creep_tau_s", "n_stacks", "adc_bits", "delay_samples"}
_SCHEMA: dict[str, Any] = {
    "study": {"name": str, "title": str, "description": str},
    "rig": {
        **{name: _NUM for name in _RIG_SCALARS},
        "n_stacks": int, "adc_bits": int, "delay_samples": int, "creep_tau_s": list,
        "stack": {f.name: (str if f.name == "name" else _NUM) for f in fields(StackData)},
    },
    "controller": {
        "Kc": _NUM, "Ti": _NUM, "Td": _NUM, "Tf_s": _NUM, "b": _NUM, "units": str, "u_min_V": _NUM, "u_max_V": _NUM,
    },
    "feedforward": {"v_max_V": _NUM, "frequency_Hz": _NUM, "cycles": int, "n_operators": int, "seed": int,
                    "data": str},
    "reference": {
        "step": {"initial_N": _NUM, "final_N": _NUM, "t_step_s": _NUM, "duration_s": _NUM},
        "trajectory": {"initial_N": _NUM, "levels_N": list, "hold_s": _NUM, "t_start_s": _NUM},
    },
    "simulation": {"seed": int, "band_N": _NUM, "signal": str},
    # the ball-screw design (piezopreload design): what the machine fixes and the design's bounds
    "ballscrew": {"nominal_diameter_mm": _NUM, "lead_mm": _NUM, "contact_angle_deg": list, "ball_mm": list,
                  "conformity": list, "turns": list, "load_sharing": _NUM},
    "feed_drive": {"table_mass_kg": _NUM, "screw_length_mm": _NUM, "bearing_stiffness_N_per_um": _NUM,
                   "travel_mm": list, "mounting": str},
    "duty": {"axial_load_N": list, "speed_rpm": list, "time_share": list},
    "design": {"objective": str, "pareto": list, "pareto_points": int, "axial_load_max_N": _NUM,
               "failsafe_load_N": _NUM, "lift_off_margin": _NUM, "preload_fraction_max": _NUM,
               "contact_pressure_max_MPa": _NUM, "life_min_h": _NUM, "drag_torque_max_Nm": _NUM,
               "frequency_min_Hz": _NUM, "stiffness_min_N_per_um": _NUM, "nut_length_max_mm": _NUM,
               "ball_lead_ratio_max": _NUM, "load_factor": _NUM, "stack_drive_V": _NUM,
               "amp_current_limit_A": _NUM},
    "schedule": {"profile": str, "stiffness_min_N_per_um": _NUM, "deflection_max_um": _NUM,
                 "lift_off_margin": _NUM},
    # the one-command study (piezopreload run): tuning, validation, export and the rig run
    "tuning": {"overshoot_margin_N": _NUM, "ms_max": _NUM, "noise_gain_max_V_per_N": _NUM,
               "tune_setpoint_weight": bool},
    "validation": {"plants": int, "seed": int, "workers": int, "settling_max_s": _NUM, "overshoot_max_N": _NUM,
                   "tracking_rms_max_N": _NUM, "peak_voltage_max_V": _NUM},
    "export": {"formats": list},
    "rig_run": {"backend": str, "reference": str, "realtime": bool, "seed": int, "force_max_N": _NUM,
                "ramp_s": _NUM, "missed_streak": int},
}
_REQUIRED = {"rig", "controller"}
_STRING_LISTS = {"design.pareto", "export.formats"}
_UNITS = ("seconds", "minutes")
_SIGNALS = ("measured_N", "force_N")
#: what [export] formats may name (rig/export.py writes each)
EXPORT_FORMATS = ("json", "labview", "plc", "c-header", "casadi-c")
_RIG_REFERENCES = ("step", "trajectory")


@dataclass(frozen=True)
class RigRunPlan:
    """The study's [rig_run]: how ``piezopreload run`` runs the validated gains on the rig."""

    backend: str = "sim"
    reference: str = "step"          # step, trajectory, or a time_s,force_N CSV (path resolved)
    realtime: bool = False           # the simulated rig runs back to back unless asked
    seed: int = 0
    force_max_N: float | None = None
    ramp_s: float | None = None
    missed_streak: int | None = None

    def safety(self) -> dict[str, float | None]:
        return {"force_max_N": self.force_max_N, "ramp_s": self.ramp_s, "missed_streak": self.missed_streak}


@dataclass(frozen=True, eq=False)
class Study:
    """A loaded, validated study."""

    path: str
    sha256: str
    name: str
    title: str
    rig: RigParams
    gains: PIDGains
    gains_units: str
    excitation: LoopExcitation
    references: dict[str, Reference]
    seed: int
    band_N: float
    signal: str
    raw: dict[str, Any]
    #: a measured voltage -> force loop to identify the feedforward from (None: simulate it)
    feedforward_data: str | None = None
    tuning_spec: TuningSpec = TuningSpec()
    criteria: Criteria = Criteria()
    validation_plants: int = 200
    validation_seed: int = 0
    validation_workers: int | None = None
    export_formats: tuple[str, ...] = EXPORT_FORMATS
    rig_run: RigRunPlan = RigRunPlan()


class _Lines:
    """Line numbers of the tables and keys of a TOML text, for messages (``a.b.key -> line``)."""

    _table = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\- ]+?)\s*\]\s*(#.*)?$")
    _key = re.compile(r"^\s*([A-Za-z0-9_\-]+)\s*=")

    def __init__(self, text: str) -> None:
        self.lines: dict[str, int] = {}
        table = ""
        for no, line in enumerate(text.splitlines(), start=1):
            m = self._table.match(line)
            if m:
                table = m.group(1).replace(" ", "")
                self.lines.setdefault(table, no)
                continue
            m = self._key.match(line)
            if m:
                self.lines.setdefault(f"{table}.{m.group(1)}" if table else m.group(1), no)

    def of(self, key_path: str) -> int | None:
        while key_path:
            if key_path in self.lines:
                return self.lines[key_path]
            key_path = key_path.rpartition(".")[0]
        return None


def _check_tree(data: dict[str, Any], schema: dict[str, Any], prefix: str, where: _Lines, shown: str) -> None:
    for key, value in data.items():
        path = f"{prefix}{key}"
        line = where.of(path)
        at = f"{shown}:{line}" if line else shown
        if key not in schema:
            known = ", ".join(sorted(schema))
            raise InputError(f"{at}: unknown key '{path}'; expected one of: {known}")
        expected = schema[key]
        if isinstance(expected, dict):
            if not isinstance(value, dict):
                raise InputError(f"{at}: '{path}' must be a table ([{path}])")
            _check_tree(value, expected, f"{path}.", where, shown)
            continue
        ok = isinstance(value, bool) if expected is bool else isinstance(value, expected) and not isinstance(value, bool)
        if not ok:
            want = {str: "a string", list: "a list", int: "an integer", _NUM: "a number",
                    bool: "true or false"}.get(expected, str(expected))
            raise InputError(f"{at}: '{path}' must be {want}, got {type(value).__name__} {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{at}: '{path}' must be finite, got {value!r}")
        if isinstance(value, list) and path in _STRING_LISTS:
            if not all(isinstance(x, str) for x in value):
                raise InputError(f"{at}: '{path}' must be a list of strings, got {value!r}")
        elif isinstance(value, list) and not all(isinstance(x, _NUM) and not isinstance(x, bool) and math.isfinite(x) for x in value):
            raise InputError(f"{at}: '{path}' must be a list of finite numbers, got {value!r}")


@dataclass(frozen=True)
class StudyText:
    """A study file read and checked against the schema (every key, every type)."""

    path: str
    sha256: str
    data: dict[str, Any]
    lines: _Lines

    def fail(self, key_path: str, message: str) -> InputError:
        """An error naming the file, the line of ``key_path`` and the key."""
        line = self.lines.of(key_path)
        return InputError(f"{self.path}:{line}: '{key_path}' {message}" if line else f"{self.path}: '{key_path}' {message}")


def read_study_text(path: str | Path, required: set[str] | frozenset[str] = frozenset()) -> StudyText:
    """Read a study file and check its keys and types; ``required`` tables must be there."""
    shown = str(path)
    raw_bytes = read_input(path, "study file")
    try:
        text = raw_bytes.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError:
        raise InputError(f"{shown}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{shown}: not valid TOML ({exc})") from None
    where = _Lines(text)
    _check_tree(data, _SCHEMA, "", where, shown)
    for section in sorted(set(required) - set(data)):
        raise InputError(f"{shown}: the table [{section}] is missing")
    return StudyText(shown, hashlib.sha256(raw_bytes).hexdigest(), data, where)


def load_study(path: str | Path) -> Study:
    """Read and validate a study file."""
    st = read_study_text(path, _REQUIRED)
    shown, data, fail = st.path, st.data, st.fail

    # ---- rig ------------------------------------------------------------------------------
    rig_data = dict(data["rig"])
    if "stack" in rig_data:
        try:
            rig_data["stack"] = StackData(**{f.name: rig_data["stack"].get(f.name, getattr(P888_91, f.name))
                                             for f in fields(StackData)})
        except ValueError as exc:
            raise fail("rig.stack", f"is not valid: {exc}") from None
    if "creep_tau_s" in rig_data:
        rig_data["creep_tau_s"] = tuple(float(x) for x in rig_data["creep_tau_s"])
    try:
        rig = RigParams(**rig_data)
    except ValueError as exc:
        name = next((k for k in rig_data if f"RigParams.{k} " in str(exc)), "")
        raise fail(f"rig.{name}" if name else "rig", f"is not valid: {exc}") from None

    # ---- controller -------------------------------------------------------------------------
    c = data["controller"]
    for key in ("Kc", "Ti", "Td"):
        if key not in c:
            raise fail("controller", f"needs '{key}'")
    units = c.get("units", "seconds")
    if units not in _UNITS:
        raise fail("controller.units", f"must be one of {', '.join(_UNITS)}, got {units!r}")
    scale = 60.0 if units == "minutes" else 1.0
    try:
        gains = PIDGains(
            Kc=float(c["Kc"]), Ti_s=scale * float(c["Ti"]), Td_s=scale * float(c["Td"]),
            Tf_s=float(c.get("Tf_s", 0.0)), b=float(c.get("b", 1.0)),
            u_min=float(c.get("u_min_V", 0.0)), u_max=float(c.get("u_max_V", 110.0)),
        )
    except ValueError as exc:
        raise fail("controller", f"is not valid: {exc}") from None

    # ---- feedforward, references, simulation -----------------------------------------------------
    try:
        excitation = LoopExcitation(**{k: v for k, v in data.get("feedforward", {}).items() if k != "data"})
    except ValueError as exc:
        raise fail("feedforward", f"is not valid: {exc}") from None
    refs = data.get("reference", {})
    references: dict[str, Reference] = {}
    try:
        s = refs.get("step", {})
        references["step"] = Reference.step(
            float(s.get("initial_N", 25.0)), float(s.get("final_N", 60.0)),
            float(s.get("t_step_s", 0.5)), float(s.get("duration_s", 10.0)),
        )
    except ValueError as exc:
        raise fail("reference.step", f"is not valid: {exc}") from None
    try:
        tr = refs.get("trajectory", {})
        hold = float(tr.get("hold_s", 5.0))
        if not hold > 0:
            raise ValueError(f"hold_s must be > 0, got {hold}")
        references["trajectory"] = Reference.staircase(
            float(tr.get("initial_N", 25.0)), tr.get("levels_N", [60.0, 80.0, 100.0, 80.0, 60.0]),
            hold, float(tr.get("t_start_s", 0.5)),
        )
    except ValueError as exc:
        raise fail("reference.trajectory", f"is not valid: {exc}") from None
    sim = data.get("simulation", {})
    band = float(sim.get("band_N", 1.5))
    if not band > 0:
        raise fail("simulation.band_N", f"must be > 0, got {band}")
    signal = sim.get("signal", "measured_N")
    if signal not in _SIGNALS:
        raise fail("simulation.signal", f"must be one of {', '.join(_SIGNALS)}, got {signal!r}")
    seed = int(sim.get("seed", 0))
    if seed < 0:
        raise fail("simulation.seed", f"must be >= 0, got {seed}")
    meta = data.get("study", {})
    here = Path(shown).parent
    ff_data = data.get("feedforward", {}).get("data")
    spec, criteria = _tuning_tables(data, gains, band, fail)
    v = data.get("validation", {})
    plants, workers = int(v.get("plants", 200)), v.get("workers")
    if not 1 <= plants <= 100_000:
        raise fail("validation.plants", f"must be in 1..100000, got {plants}")
    if workers is not None and workers < 1:
        raise fail("validation.workers", f"must be >= 1, got {workers}")
    formats = tuple(data.get("export", {}).get("formats", EXPORT_FORMATS))
    for f in formats:
        if f not in EXPORT_FORMATS:
            raise fail("export.formats", f"has {f!r}; expected some of {', '.join(EXPORT_FORMATS)}")
    return Study(
        path=shown, sha256=st.sha256, name=meta.get("name", Path(shown).stem),
        title=meta.get("title", ""), rig=rig, gains=gains, gains_units=units, excitation=excitation,
        references=references, seed=seed, band_N=band, signal=signal, raw=data,
        feedforward_data=None if ff_data is None else str(here / ff_data),
        tuning_spec=spec, criteria=criteria, validation_plants=plants,
        validation_seed=int(v.get("seed", seed)), validation_workers=workers,
        export_formats=formats, rig_run=_rig_run(data.get("rig_run", {}), here, fail),
    )


def _tuning_tables(data: dict[str, Any], gains: PIDGains, band_N: float, fail: Any) -> tuple[TuningSpec, Criteria]:
    """[tuning] as a :class:`TuningSpec` and [validation]'s limits as :class:`Criteria`."""
    t = data.get("tuning", {})
    try:
        spec = TuningSpec(band_N=band_N, u_min_V=gains.u_min, u_max_V=gains.u_max,
                          **{k: (bool(x) if k == "tune_setpoint_weight" else float(x)) for k, x in t.items()})
    except ValueError as exc:
        key = next((k for k in t if k in str(exc)), "")
        raise fail(f"tuning.{key}" if key else "tuning", f"is not valid: {exc}") from None
    limits = {k: float(x) for k, x in data.get("validation", {}).items()
              if k in ("settling_max_s", "overshoot_max_N", "tracking_rms_max_N", "peak_voltage_max_V")}
    try:
        criteria = Criteria(band_N=band_N, **limits)
    except ValueError as exc:
        key = next((k for k in limits if k in str(exc)), "")
        raise fail(f"validation.{key}" if key else "validation", f"is not valid: {exc}") from None
    return spec, criteria


def _rig_run(r: dict[str, Any], here: Path, fail: Any) -> RigRunPlan:
    reference = r.get("reference", "step")
    if reference not in _RIG_REFERENCES:
        if not reference.lower().endswith(".csv"):
            raise fail("rig_run.reference", f"must be step, trajectory or a time_s,force_N .csv file, got {reference!r}")
        reference = str(here / reference)
    for key, low in (("force_max_N", 0.0), ("ramp_s", 0.0)):
        if key in r and not r[key] > low:
            raise fail(f"rig_run.{key}", f"must be > {low:g}, got {r[key]!r}")
    if "missed_streak" in r and r["missed_streak"] < 1:
        raise fail("rig_run.missed_streak", f"must be >= 1, got {r['missed_streak']!r}")
    if r.get("seed", 0) < 0:
        raise fail("rig_run.seed", f"must be >= 0, got {r['seed']!r}")
    backend = r.get("backend", "sim")
    realtime = bool(r.get("realtime", backend != "sim"))  # a simulated plug-in may set false
    return RigRunPlan(backend=backend, reference=reference, realtime=realtime, seed=int(r.get("seed", 0)),
                      force_max_N=r.get("force_max_N"), ramp_s=r.get("ramp_s"), missed_streak=r.get("missed_streak"))


def default_study() -> Path:
    """The paper's study file as shipped with the package."""
    return Path(str(resources.files("piezopreload.studies") / DEFAULT_STUDY))
