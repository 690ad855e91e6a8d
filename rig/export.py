"""Every export format, in one module: a validated gain set, or a hysteresis model alone, as a controller reads it.

:func:`export` renders a :class:`~piezopreload.artifacts.gainset.GainSet` (only a validated one)
or an identified hysteresis model (:class:`~piezopreload.artifacts.hysteresis.IdentifiedModel`,
or a bare P-I model) in one of :data:`FORMATS`; :func:`write_exports` writes a gain set's formats
into a folder (the files :data:`EXPORT_FILES` names). What each format holds, exactly, is
``docs/exports.md``:

* ``json``: SI, the controller form spelled out, the forward P-I model and its inverse step's
  parameters by name;
* ``labview``: an INI file LabVIEW's configuration-file VIs read: Kc, and Ti and Td in minutes,
  the gain schedule's table, and the feedforward as tables (one comma-separated row per
  parameter) with the inverse step's algorithm stated above them (:data:`INVERSE_STEP_ALGORITHM`);
* ``plc``: an IEC 61131-3 Structured Text source: a gain set's whole controller step as the
  function block ``PP_CONTROLLER`` and the program ``PP_LOOP`` that calls it, written from the
  algorithm the ``casadi-c`` code is generated from; a model alone's inverse step as the function
  block ``PP_FEEDFORWARD``, generated the same way from the CasADi function its ``casadi-c`` code is
  (:mod:`piezopreload.rig.structured_text`); each block declares only what its body reads;
* ``c-header``: constants (SI) of the gains, the schedule and the forward P-I model;
* ``casadi-c``: the whole controller step (feedforward and PID with its state) as C code from
  CasADi's code generator, from the one controller step the simulation runs, its numbers a
  constant array (:mod:`piezopreload.rig.controller_code`); for a model alone, the inverse step.

The feedforward every format carries is the inverse step of
:class:`~piezopreload.models.hysteresis.InverseStep` at the loop's sample period (a gain set's
plant's; a model's own, or the one asked for): the creep lags discretised there.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import GainSet, GainsTable
from piezopreload.artifacts.hysteresis import IdentifiedModel
from piezopreload.core.artifacts import atomic_write_text
from piezopreload.core.errors import InputError
from piezopreload.core.native import generate
from piezopreload.models.controller import SCHEDULE_INTERPOLATION, Controller, GainSchedule, PIDGains
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, InverseStep, inverse_at
from piezopreload.rig.controller_code import ControllerCode, controller_code, feedforward_code
from piezopreload.rig.structured_text import controller_block, function_block, loop_program

__all__ = ["FORMATS", "EXPORT_FILES", "MODEL_FILES", "CONTROLLER_FORM", "CONTROLLER_FORM_2", "controller_form",
           "INVERSE_STEP_ALGORITHM", "ExportError",
           "NotValidated", "InverseStepTable", "export", "inverse_step_table", "write_exports",
           "controller_from_gain_set", "validated_gains", "require_validated"]

#: the formats a gain set or a hysteresis model is exported to
FORMATS = ("json", "labview", "plc", "c-header", "casadi-c")
#: the file each format of a gain set is written to in a study's exports/ folder
EXPORT_FILES = {"json": "gains.si.json", "labview": "gains.labview.txt", "plc": "gains.plc.st",
                "c-header": "pp_gains.h", "casadi-c": "pp_controller.c"}
#: the file each format of a hysteresis model alone is written to
MODEL_FILES = {"json": "feedforward.si.json", "labview": "feedforward.labview.txt", "plc": "feedforward.plc.st",
               "c-header": "pp_feedforward.h", "casadi-c": "pp_feedforward.c"}

#: the controller form every gain set's format states (models.controller.pid_update)
CONTROLLER_FORM = {
    "structure": "ideal/ISA: u = Kc (b r - y) + Kc/Ti int(e) dt - Kc Td d(y_f)/dt + u_ff",
    "integral": "trapezoidal",
    "derivative": "on the measurement, first-order filter of time constant Tf (0: unfiltered)",
    "anti_windup": "conditional integration at the output limits",
    "output_range_V": "u_min_V..u_max_V (clamped)",
    "feedforward": "inverse P-I model of the setpoint (classical, modified or the paper's asymmetric, with or without "
                   "creep), added before the clamp",
}
#: the form of a gain set with the second-order filter (``filter_order`` 2): what differs from CONTROLLER_FORM
CONTROLLER_FORM_2 = {
    **CONTROLLER_FORM,
    "structure": "ideal/ISA on the filtered measurement y_f: u = Kc (b r - y_f) + Kc/Ti int(r - y_f) dt - Kc Td "
                 "d(y_f)/dt + u_ff",
    "derivative": "on the measurement, which passes first through the second-order filter "
                  "1/(1 + Tf s + (Tf s)^2/2) (two states, Tustin's rule at the sample period; d(y_f)/dt its second "
                  "state)",
    "filter_order": 2,
}
_GAIN_KEYS = ("Kc_V_per_N", "Ti_s", "Td_s", "Tf_s", "b", "u_min_V", "u_max_V")


def controller_form(gains: PIDGains) -> dict[str, Any]:
    """The controller form a gain set's formats state: :data:`CONTROLLER_FORM`, or :data:`CONTROLLER_FORM_2` for
    the second-order filter."""
    return dict(CONTROLLER_FORM_2 if gains.filter_order == 2 else CONTROLLER_FORM)

#: the inverse step, once per sample (models.hysteresis.InverseStep), as the LabVIEW file and the docs state it;
#: the names are the feedforward table's
INVERSE_STEP_ALGORITHM = (
    "state: y[k] (k = 1..n, the play operators, V), s[j] (j = 1..m, the creep carries, V) and, direction switched,",
    "  v_prev (the last command, V); all 0 at rest at 0 V. Once per sample, for the desired force target (N):",
    "1. x = target - offset",
    "2. dead zones (d > 0): x = sum_j u[j] * S(x, dz[j]) with S = max(x - dz, 0) for dz > 0, min(x - dz, 0) for",
    "   dz < 0, x for dz = 0 (u, dz: the inverse dead-zone weights and thresholds)",
    "3. g = x - bias - sum_j c[j] * s[j]",
    "4. for each direction's weights w, partial sums W, inverse thresholds ri and inverse weights wi:",
    "   z[k] = W[k] y[k] + sum_{i>k} w[i] y[i]; z[k] = max(g - ri[k], min(g + ri[k], z[k])); v_dir = sum_k wi[k] z[k]",
    "5. one direction: v = v_rising. Direction switched: tol = 1e-9 (1 + |v_prev|); rising ok if v_rising >=",
    "   v_prev - tol, falling ok if v_falling < v_prev + tol; v_rising = max(v_rising, v_prev), v_falling =",
    "   min(v_falling, v_prev - tol); both ok: the one nearer v_prev (v_rising when v_rising - v_prev <= v_prev -",
    "   v_falling); one ok: that one; neither: v = v_prev. Then v_prev = v",
    "6. y[k] = max(v - r[k], min(v + r[k], y[k])); s[j] = a[j] s[j] + e[j] v",
    "7. the command is v (V), added to the PID's output before the output clamp",
)


class ExportError(InputError):
    """The gain set or model cannot be exported (for example: the gain set is not validated)."""


class NotValidated(ExportError):
    """A gain set whose status does not let it leave the tool (:func:`require_validated`)."""


# --------------------------------------------------------------------------------------
# the feedforward's table: the inverse step's structure and numbers at one sample period
# --------------------------------------------------------------------------------------
class InverseStepTable:
    """The inverse P-I step of a model at a sample period: its structure and its parameters by name (the table every
    format's feedforward is written from; not the study file's ``[feedforward]`` table).

    ``params`` maps each field of :attr:`InverseStep.params` (``offset_N``, ``thresholds``,
    ``weights_rising``, ...) to its numbers; ``kind`` and ``sample_period_s`` say what it is.
    """

    def __init__(self, model: HysteresisModel | CreepPI, sample_period_s: float | None) -> None:
        if isinstance(model, CreepPI):
            if sample_period_s is None:
                sample_period_s = model.sample_period_s
            model = model.with_sample_period(sample_period_s)
        try:
            structure, vector = inverse_at(model, sample_period_s or 1.0).realtime()
        except ValueError as exc:
            raise ExportError(f"field 'feedforward.model': {exc}") from exc
        self.kind: str = model.kind
        self.structure: InverseStep = structure
        self.vector = vector
        self.sample_period_s = sample_period_s
        layout = structure.params
        self.params: dict[str, np.ndarray] = {name: np.atleast_1d(np.asarray(layout.get(vector, name), float))
                                              for name in layout.names}

    @property
    def directions(self) -> tuple[str, ...]:
        return ("rising", "falling") if self.structure.asymmetric else ("rising",)

    def scalar(self, name: str) -> float:
        return float(self.params[name][0])

    def to_dict(self) -> dict[str, Any]:
        s = self.structure
        return {"kind": self.kind, "sample_period_s": self.sample_period_s, "operators": s.n_operators,
                "creep_lags": s.n_lags, "dead_zones": s.n_shaper, "direction_switched": s.asymmetric,
                "parameters": {k: (v.tolist() if s.params.field_size(k) is not None else float(v[0]))
                               for k, v in self.params.items()},
                "algorithm": list(INVERSE_STEP_ALGORITHM)}


def inverse_step_table(model: HysteresisModel | CreepPI, sample_period_s: float | None = None) -> InverseStepTable:
    """The inverse step's table of ``model`` at ``sample_period_s`` (a creep model's own period by default)."""
    return InverseStepTable(model, sample_period_s)


# --------------------------------------------------------------------------------------
# the gain set's numbers
# --------------------------------------------------------------------------------------
def require_validated(gain_set: GainSet, use: str, shown: str | None = None,
                      accepted: tuple[str, ...] = ()) -> GainSet:
    """The one check of a gain set's status before it leaves the tool: exported, run on the rig, pushed to a served rig
    or to a PLC (``use`` says which, in words: "exported", "run on the rig", ...). A gain set that is not validated
    passes only where each requirement it missed is named in ``accepted`` (:meth:`GainSet.require_usable`);
    :class:`NotValidated` (bad input) says what it missed and how to accept it by name."""
    try:
        gain_set.require_usable(accepted, shown=shown or "the gain set", use=use)
    except InputError as exc:
        raise NotValidated(str(exc)) from None
    return gain_set


def validated_gains(gain_set: GainSet, accepted: tuple[str, ...] = ()) -> dict[str, float]:
    """The gains every format writes (SI, by name); refuses a gain set that is not validated unless each requirement
    it missed is in ``accepted`` by name (:func:`require_validated`)."""
    require_validated(gain_set, "exported", accepted=accepted)
    table = GainsTable.from_value(gain_set.gains)
    g = {k: float(getattr(table, k)) for k in _GAIN_KEYS}
    bad = [k for k, v in g.items() if not np.isfinite(v)]
    if bad:
        raise ExportError(f"field 'gains.{bad[0]}' is not finite")
    return g


def _header(digest: str, gain_set: GainSet | None = None) -> list[str]:
    """The comment lines every gain set's text format starts with: its content hash, the controller form and, for a
    gain set that is not validated, what it missed and that the user accepted it by name."""
    accepted = [] if gain_set is None or gain_set.validated else [
        f"NOT VALIDATED: exported because the user accepted by name what it missed: {r.key} "
        f"({r.value:.6g} {r.unit} against {r.limit:.6g} {r.unit})" for r in gain_set.missed]
    form = CONTROLLER_FORM if gain_set is None else controller_form(gain_set.gains)
    return [f"gain set content sha256 {digest}", *accepted, "controller: " + form["structure"],
            "derivative " + form["derivative"] + "; anti-windup: " + form["anti_windup"]]


def _gain_set_table(gain_set: GainSet) -> InverseStepTable | None:
    if gain_set.feedforward is None:
        return None
    if gain_set.plant is not None:
        return inverse_step_table(gain_set.feedforward, float(gain_set.plant.sample_period_s))
    if isinstance(gain_set.feedforward, CreepPI):
        raise ExportError("field 'plant.rig' is missing: the gain set does not name its plant, whose sample period "
                          "the feedforward's creep lags are discretised at")
    return inverse_step_table(gain_set.feedforward, None)  # without creep the step does not depend on the period


# ---- json ------------------------------------------------------------------------------------
def _json_text(digest: str, g: dict[str, float], ff: dict[str, Any] | None, schedule: GainSchedule | None,
               table: InverseStepTable | None, gains: PIDGains) -> str:
    order = {} if gains.filter_order == 1 else {"filter_order": gains.filter_order}
    body: dict[str, Any] = {"gain_set_sha256": digest, "controller": controller_form(gains),
                            "gains": {**{k: g[k] for k in _GAIN_KEYS}, **order}, "feedforward_model": ff,
                            "feedforward_inverse_step": None if table is None else table.to_dict()}
    if schedule is not None:
        body["gain_schedule"] = schedule.to_dict()
    return json.dumps(body, indent=2, allow_nan=False) + "\n"


# ---- labview ----------------------------------------------------------------------------------
def _table_lines(schedule: GainSchedule, comment: str, names: tuple[tuple[str, float], ...]) -> list[str]:
    """The schedule as an INI section: the setpoints and each gain (and the setpoint weight, where the schedule has
    one per entry) as comma-separated lists, entry by entry."""
    def row(values: tuple[float, ...], divide: float) -> str:
        return ", ".join(f"{x / divide:.12g}" for x in values)

    (kc, kc_d), (ti, ti_d), (td, td_d), (b, _) = names
    return [f"{comment}gain schedule: {SCHEDULE_INTERPOLATION}; the single gains above are the robust set, "
            "not used while the schedule is", "[gain schedule]", f"entries = {schedule.size}",
            f"setpoint (N) = {row(schedule.levels_N, 1.0)}", f"{kc} = {row(schedule.Kc, kc_d)}",
            f"{ti} = {row(schedule.Ti_s, ti_d)}", f"{td} = {row(schedule.Td_s, td_d)}",
            *([] if schedule.b is None else [f"{b} = {row(schedule.b, 1.0)}"])]


def _row(values: np.ndarray) -> str:
    return ", ".join(repr(float(x)) for x in values)


def _labview_feedforward(t: InverseStepTable) -> list[str]:
    """The feedforward as INI sections: scalars, then one comma-separated row per parameter, the algorithm above."""
    s = t.structure
    lines = ["[feedforward]",
             "; the inverse P-I step, run once per sample period (the desired force in, the command out); each",
             "; row of the sections below is a table of comma-separated numbers (Spreadsheet String To Array, ',')",
             *("; " + a for a in INVERSE_STEP_ALGORITHM),
             f"model = {t.kind}",
             *([] if t.sample_period_s is None else [f"sample period (s) = {t.sample_period_s!r}"]),
             f"operators n = {s.n_operators}", f"creep lags m = {s.n_lags}", f"dead zones d = {s.n_shaper}",
             f"direction switched = {'TRUE' if s.asymmetric else 'FALSE'}",
             f"offset (N) = {t.scalar('offset_N')!r}", f"bias (N) = {t.scalar('bias')!r}",
             "[feedforward operators]", f"r threshold (V) = {_row(t.params['thresholds'])}"]
    for d in t.directions:
        lines += [f"w weight {d} (N/V) = {_row(t.params[f'weights_{d}'])}",
                  f"W partial sum {d} (N/V) = {_row(t.params[f'partial_{d}'])}",
                  f"ri inverse threshold {d} (N) = {_row(t.params[f'inverse_thresholds_{d}'])}",
                  f"wi inverse weight {d} (V/N) = {_row(t.params[f'inverse_weights_{d}'])}"]
    if s.n_shaper:
        lines += ["[feedforward dead zones]", f"dz threshold (N) = {_row(t.params['shaper_thresholds'])}",
                  f"u weight = {_row(t.params['shaper_weights'])}"]
    if s.n_lags:
        lines += ["[feedforward creep]", f"c weight (N/V) = {_row(t.params['creep_weights'])}",
                  f"a decay = {_row(t.params['creep_decay'])}", f"e input gain = {_row(t.params['creep_input'])}"]
    return lines


def _labview_text(head: list[str], g: dict[str, float], schedule: GainSchedule | None,
                  table: InverseStepTable | None) -> str:
    lines = ["; " + h for h in head] + [
        "; LabVIEW PID VIs take Ti and Td in minutes", "[PID gains]",
        f"Kc = {g['Kc_V_per_N']:.12g}", f"Ti (min) = {g['Ti_s'] / 60.0:.12g}", f"Td (min) = {g['Td_s'] / 60.0:.12g}",
        "[output range]", f"low (V) = {g['u_min_V']:.12g}", f"high (V) = {g['u_max_V']:.12g}",
        "[advanced]", f"setpoint weight beta = {g['b']:.12g}",
        f"derivative filter time constant (s) = {g['Tf_s']:.12g}"]
    if schedule is not None:  # LabVIEW's PID Gain Schedule VI takes a table of setpoint breakpoints and gains
        lines += _table_lines(schedule, "; ", (("Kc", 1.0), ("Ti (min)", 60.0), ("Td (min)", 60.0),
                                               ("setpoint weight beta", 1.0)))
    lines += ["[feedforward]", "model = none (the PID alone)"] if table is None else _labview_feedforward(table)
    return "\n".join(lines) + "\n"


# ---- plc --------------------------------------------------------------------------------------
def _plc_text(doc: GainSet, head: list[str], accepted: tuple[str, ...] = ()) -> str:
    """A Structured Text source: the controller's function block and the program that calls it."""
    code = controller_code(controller_from_gain_set(doc, accepted))
    head = ["piezopreload: a validated gain set for an IEC 61131-3 PLC.", *head,
            f"PP_CONTROLLER is the whole controller step{_structure_words(code)}; PP_LOOP calls it."]
    return controller_block(code, head) + "\n" + loop_program(code.controller.dt_s)


def _structure_words(code: ControllerCode) -> str:
    model = code.model
    parts = []
    if model.feedforward is not None:
        parts.append(f"the feedforward's inverse P-I step ({model.feedforward.n_operators} operators)")
    if model.scheduled:
        parts.append(f"the gain schedule's interpolation ({model.schedule_size} entries)")
    return "" if not parts else ", with " + " and ".join(parts)


# ---- casadi-c ---------------------------------------------------------------------------------
def controller_from_gain_set(doc: GainSet | dict[str, Any], accepted: tuple[str, ...] = ()) -> Controller:
    """The controller a validated gain set describes (or a candidate whose misses are ``accepted`` by name): gains,
    sample period and feedforward (any P-I model, with or without creep:
    :class:`~piezopreload.models.hysteresis.InverseStep`)."""
    gain_set = _gain_set(doc)
    validated_gains(gain_set, accepted)  # refuses a candidate
    try:
        return gain_set.controller()
    except ValueError as exc:
        raise ExportError(f"field 'feedforward.model': {exc}") from exc


def _schedule_comment(doc: GainSet) -> list[str]:
    """The gain schedule the generated step interpolates (its numbers are constants of the code)."""
    sch = doc.gains.schedule
    if sch is None:
        return []
    def row(values: tuple[float, ...]) -> str:
        return ", ".join(f"{x:.6g}" for x in values)
    b = "" if sch.b is None else f"; b: {row(sch.b)}"
    return [f"/* gain schedule ({sch.size} entries), compiled into the step: Kc, Ti, Td and b linear in the setpoint",
            "   between entries, the end entries' values beyond them; the integral state is the integral action (V),",
            f"   so a change of gains does not jump the output. setpoint (N): {row(sch.levels_N)};",
            f"   Kc (V/N): {row(sch.Kc)}; Ti (s): {row(sch.Ti_s)}; Td (s): {row(sch.Td_s)}{b} */"]


def _c_params(code: ControllerCode) -> str:
    """The parameter vector as a C array, each part named in a comment."""
    read = code.read
    rows = [f"  /* {p.name}: {p.description}{'' if p in read else '; not read by the step (it keeps its place)'} */ "
            + ", ".join(repr(x) for x in p.values) + "," for p in code.parameters]
    return ("static const double pp_controller_params[PP_CONTROLLER_PARAMS_SIZE] = {\n" + "\n".join(rows)
            + "\n};\n")


def _casadi_c(doc: GainSet, g: dict[str, float], digest: str, head: list[str], accepted: tuple[str, ...] = ()) -> str:
    code = controller_code(controller_from_gain_set(doc, accepted))
    controller, model, init, fn = code.controller, code.model, code.start, code.step
    n_state = model.state.size
    body = generate([init, fn], "pp_controller", inline_minmax=False)
    fields = ", ".join(f"{name} ({model.state.field_size(name) or 1})" for name in model.state.names)
    ff = model.feedforward
    ff_state = "none" if ff is None else ", ".join(
        f"{name} ({ff.state.field_size(name)})" for name in ff.state.names if ff.state.field_size(name))
    ff_state = ff_state.replace("operators", "play operator outputs, V").replace("carries", "creep carries, V").replace(
        "v_prev_V", "the last command, V")
    lines = ["/* Generated by piezopreload from a validated gain set, with CasADi's code generator. */"]
    lines += [f"/* {h} */" for h in head]
    lines += [
        f"/* sample period {controller.dt_s!r} s; output range {g['u_min_V']!r}..{g['u_max_V']!r} V */",
        f"/* state ({n_state} numbers): {fields}: the integral action (V), the previous error (N),",
        "   measurement (N) and setpoint (N), the filtered d(measurement)/dt (N/s), "
        + ("the measurement through the second-order filter (N), " if model.filter_order == 2 else "")
        + "the feedforward's",
        f"   state: its forward model's ({ff_state}); start it with pp_controller_initial_state,",
        "   then call pp_controller_step once per sample. */",
        "/* the step's numbers are the array pp_controller_params below (the names of the PLC export's",
        "   PP_CONTROLLER); the code is the algorithm the PLC export writes in Structured Text */",
        *_schedule_comment(doc),
        "/* int pp_controller_initial_state(double setpoint0, double pv0, double u0, double* state);",
        "   int pp_controller_step(double setpoint, double pv, double* state, double* u); */",
        "",
    ]
    wrapper = f"""
#define PP_GAIN_SET_SHA256 "{digest}"
#define PP_CONTROLLER_STATE_SIZE {n_state}
#define PP_CONTROLLER_PARAMS_SIZE {model.params.size}

{_c_params(code)}
/* A bumpless start: the state whose first command, with this setpoint and measurement, is u0
   (0 V for the rig at rest on its bolt preload). Returns 0 on success. */
int pp_controller_initial_state(double setpoint0, double pv0, double u0, double state[PP_CONTROLLER_STATE_SIZE]) {{
  const double* arg[{max(int(init.sz_arg()), 4)}];
  double* res[{max(int(init.sz_res()), 1)}];
  casadi_int iw[{max(int(init.sz_iw()), 1)}];
  double w[{max(int(init.sz_w()), 1)}];
  arg[0] = &setpoint0; arg[1] = &pv0; arg[2] = &u0; arg[3] = pp_controller_params;
  res[0] = state;
  return {init.name()}(arg, res, iw, w, 0);
}}

/* One sample: the command (V) for this setpoint and measurement (N); the state is updated in place.
   Returns 0 on success. */
int pp_controller_step(double setpoint, double pv, double state[PP_CONTROLLER_STATE_SIZE], double* u) {{
  const double* arg[{max(int(fn.sz_arg()), 4)}];
  double* res[{max(int(fn.sz_res()), 6)}];
  double next[PP_CONTROLLER_STATE_SIZE];
  casadi_int iw[{max(int(fn.sz_iw()), 1)}];
  double w[{max(int(fn.sz_w()), 1)}];
  int i, flag;
  arg[0] = state; arg[1] = &setpoint; arg[2] = &pv; arg[3] = pp_controller_params;
  res[0] = u; res[1] = 0; res[2] = 0; res[3] = 0; res[4] = 0; res[5] = next;
  flag = {fn.name()}(arg, res, iw, w, 0);
  if (flag) return flag;
  for (i = 0; i < PP_CONTROLLER_STATE_SIZE; ++i) state[i] = next[i];
  return 0;
}}
"""
    return "\n".join(lines) + body + wrapper


# ---- c-header ---------------------------------------------------------------------------------
def _c_array(name: str, size: str, values: Any) -> str:
    return f"static const double {name}[{size}] = {{" + ", ".join(repr(float(x)) for x in values) + "};"


def _c_model(ff: dict[str, Any]) -> list[str]:
    """The forward P-I model's numbers as C constants: its kind, operators, dead zones and creep bank."""
    kind = str(ff.get("kind", "classical"))
    r = ff.get("thresholds", [])
    lines = [f"/* forward P-I model of the feedforward, kind '{kind}' (its inverse is taken at run time; see",
             "   docs/models.md): thresholds in V, weights in N/V */",
             f'#define PP_PI_KIND "{kind}"', f"#define PP_PI_N {len(r)}",
             f"#define PP_PI_OFFSET_N {float(ff.get('offset', 0.0))!r}",
             _c_array("PP_PI_THRESHOLDS_V", "PP_PI_N", r)]
    if "weights" in ff:
        lines.append(_c_array("PP_PI_WEIGHTS_N_PER_V", "PP_PI_N", ff["weights"]))
    else:  # the paper's asymmetric model, eq. (18): weights while the input rises and while it falls
        lines += [_c_array("PP_PI_WEIGHTS_RISING_N_PER_V", "PP_PI_N", ff.get("weights_rising", [])),
                  _c_array("PP_PI_WEIGHTS_FALLING_N_PER_V", "PP_PI_N", ff.get("weights_falling", []))]
    if "deadzone_thresholds" in ff:  # the modified model: O = S(sum w F[v] + C[v] + bias) + offset
        d = ff["deadzone_thresholds"]
        lines += ["/* the modified model's dead-zone output superposition S (thresholds in N, weights 1) */",
                  f"#define PP_DZ_N {len(d)}", f"#define PP_PI_BIAS_N {float(ff.get('bias', 0.0))!r}",
                  _c_array("PP_DZ_THRESHOLDS_N", "PP_DZ_N", d),
                  _c_array("PP_DZ_WEIGHTS", "PP_DZ_N", ff.get("deadzone_weights", []))]
    creep = ff.get("creep")
    if isinstance(creep, dict):
        tau = creep.get("time_constants_s", [])
        lines += ["/* creep: first-order lags on the input, C[v] = sum c_j L_j[v], tau_j dL_j/dt = v - L_j, added to",
                  "   the operators' sum; sampled exactly for an input linear between samples */",
                  f"#define PP_CREEP_N {len(tau)}",
                  f"#define PP_CREEP_SAMPLE_PERIOD_S {float(creep.get('sample_period_s', 0.0))!r}",
                  _c_array("PP_CREEP_TIME_CONSTANTS_S", "PP_CREEP_N", tau),
                  _c_array("PP_CREEP_WEIGHTS_N_PER_V", "PP_CREEP_N", creep.get("weights", []))]
    return lines


def _c_schedule(schedule: GainSchedule) -> list[str]:
    """The gain schedule as C arrays, with the interpolation the controller step does spelled out."""
    b = "Kc, Ti, Td and b" if schedule.b is not None else "Kc, Ti and Td"
    single = ("Tf and the output range are single;" if schedule.b is not None else
              "Tf, b (PP_SETPOINT_WEIGHT) and the output range are single;")
    robust = "PP_KC_V_PER_N, PP_TI_S, PP_TD_S" + (" and PP_SETPOINT_WEIGHT" if schedule.b is not None else "")
    return [f"/* gain schedule: {b} linear in the setpoint r between entries, the end entries' values",
            "   beyond them: for PP_SCHEDULE_LEVELS_N[i] <= r <= PP_SCHEDULE_LEVELS_N[i+1],",
            f"   K(r) = K[i] + (K[i+1] - K[i]) (r - L[i]) / (L[i+1] - L[i]). {single}",
            "   the integral state is the integral action (V), so a change of gains does not jump the output.",
            f"   {robust} above are the robust set, not used while the schedule is. */",
            f"#define PP_SCHEDULE_N {schedule.size}",
            _c_array("PP_SCHEDULE_LEVELS_N", "PP_SCHEDULE_N", schedule.levels_N),
            _c_array("PP_SCHEDULE_KC_V_PER_N", "PP_SCHEDULE_N", schedule.Kc),
            _c_array("PP_SCHEDULE_TI_S", "PP_SCHEDULE_N", schedule.Ti_s),
            _c_array("PP_SCHEDULE_TD_S", "PP_SCHEDULE_N", schedule.Td_s),
            *([] if schedule.b is None else [_c_array("PP_SCHEDULE_B", "PP_SCHEDULE_N", schedule.b)])]


def _c_header(digest: str, head: list[str], g: dict[str, float], ff: dict[str, Any] | None,
              schedule: GainSchedule | None = None, order: int = 1) -> str:
    lines = ["/* Generated by piezopreload from a validated gain set. */"]
    lines += [f"/* {h} */" for h in head]
    lines += ["#ifndef PIEZOPRELOAD_GAINS_H", "#define PIEZOPRELOAD_GAINS_H", ""]
    lines += [f'#define PP_GAIN_SET_SHA256 "{digest}"', f"#define PP_KC_V_PER_N {g['Kc_V_per_N']!r}",
              f"#define PP_TI_S {g['Ti_s']!r}", f"#define PP_TD_S {g['Td_s']!r}", f"#define PP_TF_S {g['Tf_s']!r}",
              f"#define PP_SETPOINT_WEIGHT {g['b']!r}", f"#define PP_U_MIN_V {g['u_min_V']!r}",
              f"#define PP_U_MAX_V {g['u_max_V']!r}"]
    if order == 2:
        lines += ["/* the filter's order: 2, the measurement through 1/(1 + Tf s + (Tf s)^2/2) by Tustin's rule, as",
                  "   pp_controller.c (format casadi-c) runs it */", "#define PP_FILTER_ORDER 2"]
    if schedule is not None:
        lines += [""] + _c_schedule(schedule)
    if ff is not None:
        lines += [""] + _c_model(ff)
    lines += ["", "#endif"]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------
# a hysteresis model alone
# --------------------------------------------------------------------------------------
def _model_head(record: IdentifiedModel | None, t: InverseStepTable) -> list[str]:
    period = "any (no creep)" if t.sample_period_s is None else f"{t.sample_period_s!r} s"
    head = [f"piezopreload: the feedforward of a {t.kind} P-I model alone (no PID gains), its inverse step at the "
            f"sample period {period}"]
    if record is not None:
        head.append(f"identified on {record.data.kind} data sha256 {record.data.sha256}, "
                    f"over {record.output_range[0]:.6g} to {record.output_range[1]:.6g} {record.units.output}; "
                    f"fit {record.fit.rms_pct:.4g} % RMS of the span")
    return head


def _model_casadi_c(t: InverseStepTable, head: list[str]) -> str:
    code = feedforward_code(t.structure, t.vector)
    s, fn = t.structure, code.step
    body = generate([fn], "pp_feedforward", inline_minmax=False)
    rows = [f"  /* {p.name}: {p.description} */ " + ", ".join(repr(x) for x in p.values) + ","
            for p in code.parameters]
    lines = ["/* Generated by piezopreload with CasADi's code generator. */", *(f"/* {h} */" for h in head),
             f"/* state ({s.n_states} numbers): {', '.join(n for n in s.state.names if s.state.field_size(n))}; 0 at",
             "   rest at 0 V. int pp_feedforward_step(double target, double* state, double* command); */",
             "/* the step's numbers are the array pp_feedforward_params below (the names of the PLC export's",
             "   PP_FEEDFORWARD); the code is the algorithm the PLC export writes in Structured Text */", ""]
    wrapper = f"""
#define PP_FEEDFORWARD_STATE_SIZE {s.n_states}
#define PP_FEEDFORWARD_PARAMS_SIZE {s.params.size}

static const double pp_feedforward_params[PP_FEEDFORWARD_PARAMS_SIZE] = {{
{chr(10).join(rows)}
}};

/* One sample: the command (V) that makes the model give the force target (N); the state is updated in place. */
int pp_feedforward_step(double target, double state[PP_FEEDFORWARD_STATE_SIZE], double* command) {{
  const double* arg[{max(int(fn.sz_arg()), 3)}];
  double* res[{max(int(fn.sz_res()), 2)}];
  double next[PP_FEEDFORWARD_STATE_SIZE];
  casadi_int iw[{max(int(fn.sz_iw()), 1)}];
  double w[{max(int(fn.sz_w()), 1)}];
  int i, flag;
  arg[0] = state; arg[1] = &target; arg[2] = pp_feedforward_params;
  res[0] = command; res[1] = next;
  flag = {fn.name()}(arg, res, iw, w, 0);
  if (flag) return flag;
  for (i = 0; i < PP_FEEDFORWARD_STATE_SIZE; ++i) state[i] = next[i];
  return 0;
}}
"""
    return "\n".join(lines) + body + wrapper


def _export_model(obj: IdentifiedModel | HysteresisModel | CreepPI, fmt: str, sample_period_s: float | None) -> str:
    record = obj if isinstance(obj, IdentifiedModel) else None
    model = obj.model if isinstance(obj, IdentifiedModel) else obj
    t = inverse_step_table(model, sample_period_s)
    head = _model_head(record, t)
    if fmt == "json":
        body = {"feedforward_model": model.to_dict(), "feedforward_inverse_step": t.to_dict(),
                "identified": None if record is None else record.to_dict()["identification"]}
        return json.dumps(body, indent=2, allow_nan=False) + "\n"
    if fmt == "labview":
        return "\n".join(["; " + h for h in head] + _labview_feedforward(t)) + "\n"
    if fmt == "plc":
        return "(* " + "\n   ".join(head) + " *)\n\n" + function_block(t)
    if fmt == "c-header":
        lines = [f"/* {h} */" for h in head] + ["#ifndef PIEZOPRELOAD_FEEDFORWARD_H",
                                                "#define PIEZOPRELOAD_FEEDFORWARD_H",
                                                 "", *_c_model(model.to_dict()), "", "#endif"]
        return "\n".join(lines) + "\n"
    return _model_casadi_c(t, head)


# --------------------------------------------------------------------------------------
# the one entry point
# --------------------------------------------------------------------------------------
def _export_gain_set(gain_set: GainSet, fmt: str, accepted: tuple[str, ...] = ()) -> str:
    g = validated_gains(gain_set, accepted)
    digest = gain_set.content_sha256 or ""
    head, schedule = _header(digest, gain_set), gain_set.gains.schedule
    ff = None if gain_set.feedforward is None else gain_set.feedforward.to_dict()
    if fmt == "casadi-c":
        return _casadi_c(gain_set, g, digest, head, accepted)
    if fmt == "c-header":  # the forward model's constants, its creep with the period it was identified at
        return _c_header(digest, head, g, ff, schedule, gain_set.gains.filter_order)
    if fmt == "plc":
        return _plc_text(gain_set, head, accepted)
    table = _gain_set_table(gain_set)
    if fmt == "json":
        return _json_text(digest, g, ff, schedule, table, gain_set.gains)
    if gain_set.gains.filter_order == 2:
        raise ExportError("field 'gains.filter_order' is 2: LabVIEW's PID VIs filter the derivative in first order "
                          "only, so they would not run this controller; export it as 'plc' (Structured Text) or "
                          "'casadi-c' (the controller step in C), which run its second-order filter")
    return _labview_text(head, g, schedule, table)


def _gain_set(doc: GainSet | dict[str, Any]) -> GainSet:
    return doc if isinstance(doc, GainSet) else GainSet.from_dict(doc)


def export(obj: GainSet | IdentifiedModel | HysteresisModel | CreepPI | dict[str, Any], fmt: str, *,
           sample_period_s: float | None = None, accepted: tuple[str, ...] = ()) -> str:
    """``obj`` in format ``fmt`` (one of :data:`FORMATS`), as text: exactly what ``piezopreload export`` writes.

    Parameters
    ----------
    obj : GainSet, IdentifiedModel, a P-I model, or a gain set's document
        A gain set (only a validated one is exported), or a hysteresis model alone (its
        feedforward: the inverse step, no PID gains).
    fmt : str
        ``json``, ``labview``, ``plc``, ``c-header`` or ``casadi-c``.
    sample_period_s : float, optional
        A model alone: the loop's sample period its creep lags are discretised at (default: the
        model's own). A gain set's is its plant's: giving another is refused.
    accepted : tuple of str
        A gain set that is not validated is exported only where every requirement it missed is
        named here (:attr:`~piezopreload.artifacts.requirements.Requirement.key`); the text
        then says so in its header.

    Returns
    -------
    str
        The export's text (a JSON document, a LabVIEW table, Structured Text, C source).

    Raises
    ------
    ExportError
        For an unknown format, a gain set that is not validated (and whose misses are not accepted), or a
        sample period given with a gain set.
    """
    if fmt not in FORMATS:
        raise ExportError(f"unknown format '{fmt}'; expected one of {', '.join(FORMATS)}")
    if isinstance(obj, GainSet | dict):
        if sample_period_s is not None:
            raise ExportError("a gain set's feedforward runs at its plant's sample period: sample_period_s is for a "
                              "hysteresis model alone")
        return _export_gain_set(_gain_set(obj), fmt, accepted)
    if isinstance(obj, IdentifiedModel) or callable(getattr(obj, "inverse_spec", None)):
        return _export_model(obj, fmt, sample_period_s)
    raise ExportError(f"cannot export a {type(obj).__name__}: give a GainSet, an IdentifiedModel or a P-I model")


def write_exports(gain_set: GainSet, folder: str | Path, formats: tuple[str, ...] | list[str] = FORMATS,
                  accepted: tuple[str, ...] = ()) -> dict[str, Path]:
    """Write ``formats`` of a validated gain set (or one whose misses are ``accepted`` by name) into ``folder`` (one
    file each, named by :data:`EXPORT_FILES`)."""
    written = {}
    for fmt in formats:
        text = export(gain_set, fmt, accepted=accepted)
        path = Path(folder) / EXPORT_FILES[fmt]
        atomic_write_text(path, text)
        written[fmt] = path
    return written
