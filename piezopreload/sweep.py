"""Design sweeps: a study at every point of a grid of values of its keys, each point through the study pipeline.

``piezopreload sweep STUDY --vary TABLE.KEY=V1,V2,... [--vary ...] [--grid|--zip]`` and
``study.sweep({"tuning.ms_max": [1.4, 1.6, 1.8], ...})``:

- each point is the study with its values, made by :meth:`StudySpec.replace
  <piezopreload.spec.StudySpec.replace>` (checked as a study file is; a key the designed plant sets
  is refused there), and every point is made and checked before any runs;
- each point runs through :func:`piezopreload.pipeline.run_study` into its own folder,
  ``OUT/points/pNNN/`` (its ``study.toml``, ``pipeline.json``, artifacts, report and
  ``sweep-point.log``, its progress); the points share one
  :class:`~piezopreload.core.stagecache.StageCache` (``OUT/cache/``), so a stage whose content key
  two points share is computed once and restored into the other's folder;
- the points run in local worker processes (``workers``, default one per CPU) or on a Dask
  cluster (``scheduler``, the ``dask`` extra); each process runs its point's stages with one worker
  (``run_study(..., workers=1)``), so the points are the parallel work. A point that fails is
  recorded with its error and the stage that failed, and the others go on;
- ``OUT/sweep.json`` (:class:`~piezopreload.artifacts.sweep.SweepRecord`) is written before the
  first point and again as each one ends; ``OUT/sweep.csv`` holds the rows, and ``OUT/report.pdf``
  the sweep's report. A sweep that was stopped is resumed by running it again: a finished point's
  stages are up to date in its folder (their content keys), and shared stages are in the store.

A point's headline figures (:class:`~piezopreload.artifacts.sweep.PointFigures`) come from its
``pipeline.json`` (the stages' records), its gain set (the validation's verdict and worst cases,
also where the validation failed) and its run's summary (:func:`piezopreload.pipeline.run_summary`).
The folders must be on a file system every worker sees at the same path.
"""

from __future__ import annotations

import csv
import io
import itertools
import multiprocessing
import os
import re
import time
import tomllib
import uuid
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.manifest import StudyRunManifest
from piezopreload.artifacts.requirements import EXIT_REQUIREMENT_MISSED
from piezopreload.artifacts.summaries import CompareSummary, DesignSummary, RigSummary, SystemSummary, TuneSummary
from piezopreload.artifacts.sweep import (
    DEFAULT_SWEEP_OUT,
    EXIT_POINT_FAILED,
    MODES,
    PointFigures,
    Scalar,
    SweepAxis,
    SweepPoint,
    SweepRecord,
)
from piezopreload.artifacts.system import SystemRecord
from piezopreload.artifacts.thermal import ThermalRecord
from piezopreload.core.artifacts import atomic_write_text
from piezopreload.core.errors import InputError, InternalError, PiezopreloadError
from piezopreload.core.parallel import Pool, default_workers
from piezopreload.core.stagecache import StageCache
from piezopreload.core.stages import locked, utc
from piezopreload.outcome import RunSummary
from piezopreload.pipeline import read_template, run_study, run_summary
from piezopreload.progress import Progress, ProgressLike, as_progress
from piezopreload.spec import StudySpec
from piezopreload.tuning.validate import SchedulerError

if TYPE_CHECKING:  # the sweep's report and figures load matplotlib when they are drawn, not when a study is read
    from matplotlib.figure import Figure

__all__ = ["sweep", "SweepResult", "SweepReport", "parse_vary", "plan_points", "headline", "rerender_sweep_report",
           "is_sweep_folder", "DEFAULT_SWEEP_OUT", "EXIT_POINT_FAILED"]

RECORD, ROWS, CACHE, POINTS, POINT_LOG = "sweep.json", "sweep.csv", "cache", "points", "sweep-point.log"


# --------------------------------------------------------------------------------------
# the points
# --------------------------------------------------------------------------------------
_BARE = re.compile(r"[^\s\[\]{}\"'=,#]+")  # a string without quotes: a word, a file name


def _value(text: str, where: str) -> Scalar:
    """One value as TOML reads it (``30``, ``1.5``, ``true``, ``"text"``); a bare word is a string."""
    text = text.strip()
    if not text:
        raise InputError(f"{where}: an empty value; give V1,V2,... (example: --vary tuning.ms_max=1.4,1.6)")
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        value = text if _BARE.fullmatch(text) else None
    if not isinstance(value, bool | int | float | str):
        raise InputError(f"{where}: '{text}' is not a number, a string or a boolean (a string with spaces or commas "
                         'in quotes: "a b")')
    return value


def parse_vary(text: str, option: str = "--vary") -> tuple[str, list[Scalar]]:
    """``'tuning.ms_max=1.4,1.6'`` -> ``('tuning.ms_max', [1.4, 1.6])``; bad text raises
    :class:`InputError` naming ``option``."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or "." not in key or not all(key.split(".")):
        raise InputError(f"{option} '{text}': expected TABLE.KEY=V1,V2,... (example: "
                         f"{option} rig.bolt_preload_N=20,25,30)")
    return key, [_value(v, f"{option} {key}") for v in values.split(",")]


def _label(values: Mapping[str, Scalar]) -> str:
    return ", ".join(f"{k}={v}" for k, v in values.items())


def _changes(values: Mapping[str, Scalar]) -> dict[str, Any]:
    """``{"reference.step.final_N": 80}`` -> ``{"reference": {"step": {"final_N": 80}}}`` (``replace``'s form)."""
    changes: dict[str, Any] = {}
    for key, value in values.items():
        *tables, name = key.split(".")
        node = changes
        for t in tables:
            node = node.setdefault(t, {})
        node[name] = value
    return changes


def plan_points(study: StudySpec, vary: Mapping[str, Sequence[Scalar]], mode: str = "grid",
                where: str = "Study.sweep") -> tuple[tuple[SweepAxis, ...], list[tuple[dict[str, Scalar], StudySpec]]]:
    """The axes and, per point, its values and its study (``study.replace`` with them), every point checked.

    ``mode``: ``grid`` (every combination, the last axis fastest) or ``zip`` (the i-th value of each
    axis together; the axes must be as long). Raises :class:`InputError` naming ``where`` and the point.
    """
    if mode not in MODES:
        raise InputError(f"{where}: mode must be one of {', '.join(MODES)}, got {mode!r}")
    if not vary:
        raise InputError(f"{where}: nothing to vary; give at least one key with its values (TABLE.KEY=V1,V2,...)")
    try:
        axes = tuple(SweepAxis(str(k), tuple(v)) for k, v in vary.items())
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {exc}") from None
    lengths = {a.key: len(a.values) for a in axes}
    if mode == "zip" and len(set(lengths.values())) > 1:
        raise InputError(f"{where}: --zip pairs the i-th values of every key, so each needs as many values; got "
                         + ", ".join(f"{k} {n}" for k, n in lengths.items()) + " (or sweep the --grid)")
    combos = itertools.product(*(a.values for a in axes)) if mode == "grid" else zip(*(a.values for a in axes))
    points = []
    for combo in combos:
        values = dict(zip((a.key for a in axes), combo))
        try:
            points.append((values, study.replace(**_changes(values))))
        except PiezopreloadError as exc:
            raise InputError(f"{where}: the point {_label(values)}: {exc}") from None
    return axes, points


#: the [tuning] limits a sweep may relax, with the direction in which a value is tighter (-1: a smaller value)
RELAXED_LIMITS = {"tuning.ms_max": -1, "tuning.noise_gain_max_V_per_N": -1, "tuning.overshoot_margin_N": +1}


def _tighter(a: Mapping[str, Scalar], b: Mapping[str, Scalar]) -> bool:
    """Whether point ``b``'s tuning problem is point ``a``'s with limits as tight or tighter and nothing else changed
    (the same plant, references and objective: ``b``'s tuned gains meet ``a``'s limits)."""
    changed = [k for k in a if a[k] != b[k]]
    return bool(changed) and all(
        k in RELAXED_LIMITS and isinstance(a[k], int | float) and isinstance(b[k], int | float)
        and RELAXED_LIMITS[k] * (float(b[k]) - float(a[k])) > 0 for k in changed)


def tighter_neighbours(values: Sequence[Mapping[str, Scalar]]) -> dict[int, int]:
    """For each point whose limits another point's relaxes (:data:`RELAXED_LIMITS`, nothing else changed), the closest
    such tighter point: its index. A looser point's tuning starts from that point's gains (``[tuning] warm_start``),
    which meet its limits, so relaxing a limit never loses what the tighter point found."""
    out: dict[int, int] = {}
    for i, a in enumerate(values):
        found = [j for j, b in enumerate(values) if j != i and _tighter(a, b)]
        # the closest: no other tighter point lies between it and this one
        closest = [j for j in found if not any(_tighter(values[k], values[j]) for k in found if k != j)]
        if closest:
            out[i] = min(closest)
    return out


def _waves(n: int, after: Mapping[int, int]) -> list[list[int]]:
    """The points in waves: each point in the wave after the one its tighter neighbour is in."""
    depth: dict[int, int] = {}

    def level(i: int) -> int:
        if i not in depth:
            depth[i] = 0 if i not in after else level(after[i]) + 1
        return depth[i]

    waves: list[list[int]] = [[] for _ in range(max((level(i) for i in range(n)), default=-1) + 1)]
    for i in range(n):
        waves[level(i)].append(i)
    return waves


# --------------------------------------------------------------------------------------
# one point (in a worker)
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Task:
    index: int
    values: dict[str, Scalar]
    folder: str        # relative to out
    study: StudySpec
    out: str           # the sweep's folder, absolute
    force: bool
    workers: int       # the point's run's worker processes (1 where the points are the parallel work)


def run_point(task: _Task) -> SweepPoint:
    """Run one point into its folder (sharing the sweep's stage store) and read its headline figures."""
    t0 = time.perf_counter()
    folder = Path(task.out) / task.folder
    folder.mkdir(parents=True, exist_ok=True)
    cache = StageCache(Path(task.out) / CACHE)
    status, error, stage = "done", None, None
    code: int | None = None
    ran: tuple[str, ...] = ()
    summary: RunSummary | None = None
    with open(folder / POINT_LOG, "w", encoding="utf-8") as log:
        try:
            result = run_study(task.study, folder, force=task.force, progress=Progress(stream=log), cache=cache,
                               workers=task.workers)
            summary, ran = result.summary, tuple(s for s in result.ran if s not in cache.reused)
        except PiezopreloadError as exc:
            status, error, stage = "failed", str(exc), getattr(exc, "stage", None)
            code = int(getattr(exc, "exit_code", 1 if isinstance(exc, InternalError) else 2))
        except Exception as exc:  # an internal failure of this point; the others go on
            status, error, code = "failed", f"internal failure: {type(exc).__name__}: {exc}", 1
        if error is not None:  # paths in the sweep's folder as the rows name the points', relative to it
            error = error.replace(f"{Path(task.out)}{os.sep}", "")
        log.write(f"point {task.index}: {status}{'' if error is None else ': ' + error}\n")
    return SweepPoint(task.index, task.values, task.folder, status, error, stage, code, time.perf_counter() - t0, ran,
                      tuple(cache.reused), headline(folder, summary))


def _gain_set(folder: Path, manifest: StudyRunManifest) -> GainSet | None:
    """The point's gain set: validated, or the candidate a failed validation left (its verdict and worst cases)."""
    record = manifest.record("validate")
    out = None if record is None else record.outputs.get("gains")
    if out is None:
        return None
    try:
        return GainSet.load(folder / out.path)
    except PiezopreloadError:
        return None


def _thermal(folder: Path, manifest: StudyRunManifest) -> ThermalRecord | None:
    """The shift's thermal budget as the point's system artifact records it (None: no system stage, or no
    ``[thermal]`` table)."""
    record = manifest.record("system")
    out = None if record is None or not record.done else record.outputs.get("system")
    if out is None:
        return None
    try:
        return SystemRecord.load(folder / out.path).thermal
    except PiezopreloadError:
        return None


def headline(folder: str | Path, summary: RunSummary | None = None) -> PointFigures:
    """A point's headline figures from its folder (``pipeline.json``, the gain set) and its run's ``summary``
    (default: :func:`~piezopreload.pipeline.run_summary` of the folder, also for a run that stopped at a stage)."""
    folder = Path(folder)
    try:
        manifest = StudyRunManifest.load(folder)
        summary = run_summary(folder) if summary is None else summary
    except PiezopreloadError:  # the point stopped before its first stage was recorded
        return PointFigures()
    tune, design = manifest.summary(TuneSummary), manifest.summary(DesignSummary)
    compare, rig = manifest.summary(CompareSummary), manifest.summary(RigSummary)
    system = manifest.summary(SystemSummary)
    gain_set = _gain_set(folder, manifest)
    validation = None if gain_set is None else gain_set.validation
    thermal = _thermal(folder, manifest)  # the shift, for the schedule (s) and the best constant preload (c)
    s, c = (None, None) if thermal is None else (thermal.schedule, thermal.constant)
    worst = None if validation is None else validation.worst
    h = summary.headline
    energy, saved = h.friction_energy_per_cycle, h.friction_saved_fraction
    return PointFigures(
        design_stiffness_N_per_um=None if design is None else design.stiffness_N_per_um,
        Kc_V_per_N=None if tune is None else tune.Kc_V_per_N, Ti_s=None if tune is None else tune.Ti_s,
        Td_s=None if tune is None else tune.Td_s, Tf_s=None if tune is None else tune.Tf_s,
        b=None if tune is None else tune.b, ms=None if tune is None else tune.ms,
        gain_schedule=None if tune is None else tune.gain_schedule,
        gain_set_status=None if gain_set is None else gain_set.status,
        validation_plants=None if validation is None else validation.n_plants,
        validation_failures=None if validation is None else len(validation.failures),
        worst_settling_s=None if worst is None else worst.settling_s,
        worst_overshoot_N=None if worst is None else worst.overshoot_N,
        worst_tracking_rms_N=None if worst is None else worst.tracking_rms_N,
        worst_peak_voltage_V=None if worst is None else worst.peak_voltage_V,
        tuned_settling_s=None if compare is None else compare.tuned_settling_s,
        tracking_rms_N=h.tracking_rms_N, tracking_rms_pct_of_range=h.tracking_rms_pct_of_range,
        tracking_rms_pct_of_range_before_learning=h.tracking_rms_pct_of_range_before_learning,
        tracking_max_N=h.tracking_max_N, rigidity_min_cutting_N_per_um=h.rigidity_min_cutting_N_per_um,
        rigidity_required_at_min_N_per_um=h.rigidity_required_at_min_N_per_um, rigidity_ratio_min=h.rigidity_ratio_min,
        deflection_max_um=h.nut_axial_deflection_max_um, rig_tracking_rms_N=h.rig_tracking_rms_N,
        friction_energy_per_cycle=energy, energy_units=None if system is None else system.numbers.energy_units,
        constant_friction_energy_per_cycle=(None if energy is None or design is None
                                            else design.constant_friction_energy),
        friction_saving_pct=None if saved is None else 100.0 * saved,
        heat_mean_W=None if s is None else s.heat_mean_W, constant_heat_mean_W=None if c is None else c.heat_mean_W,
        temperature_rise_max_K=None if s is None else s.temperature_rise_max_K,
        constant_temperature_rise_max_K=None if c is None else c.temperature_rise_max_K,
        growth_max_um=None if s is None else s.growth_max_um,
        constant_growth_max_um=None if c is None else c.growth_max_um,
        positioning_error_max_um=None if s is None else s.positioning_error_max_um,
        constant_positioning_error_max_um=None if c is None else c.positioning_error_max_um,
        rig_status=None if rig is None else rig.status,
        requirements_met=summary.requirements_met, requirements_missed=tuple(r.to_dict() for r in summary.missed))


# --------------------------------------------------------------------------------------
# running the points
# --------------------------------------------------------------------------------------
def _lost(task: _Task, exc: BaseException) -> SweepPoint:
    """A point whose worker was lost (a killed process, a lost Dask worker): failed, with what its folder holds."""
    return SweepPoint(task.index, task.values, task.folder, "failed",
                      f"its worker was lost: {type(exc).__name__}: {exc}", None, 1, None, (), (),
                      headline(Path(task.out) / task.folder))


def _run_local(tasks: list[_Task], workers: int, done: Callable[[SweepPoint], None]) -> None:
    # fresh processes: a forked one inherits the threads' locks of whatever ran here before (Typst's compiler
    # threads, after a report: a forked point then hangs in its own report); they import the package once each
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = {pool.submit(run_point, t): t for t in tasks}
        for fut in as_completed(futures):
            try:
                point = fut.result()
            except Exception as exc:  # the worker process died (killed, out of memory)
                point = _lost(futures[fut], exc)
            done(point)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_dask(tasks: list[_Task], scheduler: str, done: Callable[[SweepPoint], None]) -> None:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise SchedulerError("--scheduler needs Dask distributed: pip install 'piezopreload[dask]'") from None
    try:
        client = Client(scheduler, timeout=10)
    except (OSError, TimeoutError) as exc:
        raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    try:
        run = uuid.uuid4().hex[:8]
        futures = [client.submit(run_point, t, key=f"piezopreload-sweep-{run}-{t.index}", pure=False) for t in tasks]
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        for fut in dask_completed(futures):
            try:
                point = fut.result()
            except Exception as exc:  # a worker lost with the point, or the task could not be sent
                point = _lost(by_key[fut.key], exc)
            done(point)
    finally:
        client.close()


def _warm_started(task: _Task, tighter: _Task | None, progress: Progress) -> _Task:
    """``task`` with its tuning started from its tighter neighbour's tuned gains, where that point wrote them."""
    if tighter is None:
        return task
    tuning = Path(tighter.out) / tighter.folder / "tuning.json"
    if not tuning.is_file():
        progress.write(f"p{task.index:03d}: its tighter point p{tighter.index:03d} wrote no tuning; it is tuned "
                       "from its own starts only\n")
        return task
    changed = {k: v for k, v in tighter.values.items() if v != task.values[k]}
    progress.write(f"p{task.index:03d}: its tuning starts from p{tighter.index:03d}'s gains, which meet its limits "
                   f"(p{tighter.index:03d} has them tighter: {_label(changed)})\n")
    return replace(task, study=task.study.replace(tuning={"warm_start": str(tuning)}))


def _point_line(point: SweepPoint, count: int, total: int) -> str:
    head = f"[{count}/{total}] p{point.index:03d} {_label(point.values)}: "
    took = "" if point.seconds is None else f" in {point.seconds:.1f} s"
    if point.status == "failed":
        return head + f"FAILED{took}: {point.error}\n"
    ran = f"ran {', '.join(point.ran)}" if point.ran else "nothing to run"
    reused = f"; reused {', '.join(point.reused)}" if point.reused else ""
    return head + f"done{took} ({ran}{reused})\n"


def _check_where(workers: int | None, scheduler: str | None) -> None:
    if workers is not None and scheduler is not None:
        raise InputError("--workers and --scheduler: give one (local worker processes or a Dask cluster), not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError(f"--workers: must be a whole number >= 1, got {workers!r}")
    if scheduler is not None and not str(scheduler).startswith("tcp://"):
        raise InputError(f"--scheduler: '{scheduler}' is not a Dask scheduler address tcp://HOST:PORT")


def sweep(study: StudySpec, vary: Mapping[str, Sequence[Scalar]], *, mode: str = "grid",
          out: str | Path = DEFAULT_SWEEP_OUT, workers: int | None = None, scheduler: str | None = None,
          force: bool = False, progress: ProgressLike | None = None, report: bool = True,
          where: str = "Study.sweep") -> SweepResult:
    """Run ``study`` at every point of ``vary`` (key -> values) into ``out``; see the module docstring.

    Parameters
    ----------
    study : StudySpec
        The study swept.
    vary : mapping of str to list
        ``{"TABLE.KEY": [V1, V2, ...]}``: the keys as a study file's tables name them
        (``reference.step.final_N`` for a nested one).
    mode : {"grid", "zip"}
        Every combination of the values, or the i-th values of the keys together.
    out : str or Path
        The sweep's folder (points, shared stages, rows, report).
    workers, scheduler : int or str, optional
        Local worker processes (default: one per CPU, at most one per point; 1 runs the points
        here, one after another) or a Dask scheduler's address ``tcp://HOST:PORT``.
    force : bool
        Run every stage of every point again (the shared stages once each).
    progress : ProgressLike, optional
        Where each point's line goes: a function given each line, or a
        :class:`~piezopreload.progress.Progress` (default: standard error).
    report : bool
        Typeset the sweep's report (``OUT/report.pdf``) at the end.
    where : str
        How errors name the caller (``--vary`` on the command line).

    Returns
    -------
    SweepResult
        One row per point; a point that failed is a row with its error.
    """
    _check_where(workers, scheduler)
    reporter = as_progress(progress)
    t0 = time.perf_counter()
    axes, planned = plan_points(study, vary, mode, where)
    study.check_files()
    out = Path(out).absolute()
    with locked(out, f"{out}: another sweep is writing this folder; wait for it or give another --out"):
        # what a killed sweep left half-stored goes; with force, the whole store (the shared stages run once again)
        StageCache(out / CACHE).clean(everything=force)
        record = SweepRecord(study.name, study.path, study.sha256, mode, axes,
                             tuple(SweepPoint(i, values, f"{POINTS}/p{i:03d}")
                                   for i, (values, _) in enumerate(planned)),
                             utc())
        record.save(out / RECORD)
        here = default_workers()  # the one read of the user's setting: a point run in this process has this many
        n = min(workers or here, len(planned))
        reporter.write(f"sweep of {study.name}: {len(planned)} points ({mode}: "
                       + " x ".join(f"{a.key} {len(a.values)}" for a in axes) + "), on "
                       + (f"the Dask cluster {scheduler}" if scheduler else
                          f"{n} local worker processes" if n > 1 else "this process, one after another")
                       + f"; outputs in {out}/\n")
        # a point in a worker runs its stages one job after another (the points are the parallel work); one run
        # here has the processes a study run has
        tasks = [_Task(i, values, f"{POINTS}/p{i:03d}", s, str(out), force, 1) for i, (values, s) in enumerate(planned)]
        count = 0

        def done(point: SweepPoint) -> None:
            nonlocal record, count
            record = record.with_point(point)
            record.save(out / RECORD)
            count += 1
            reporter.write(_point_line(point, count, len(tasks)))

        after = tighter_neighbours([v for v, _ in planned])
        for wave in _waves(len(tasks), after):
            batch = [_warm_started(tasks[i], tasks[after[i]] if i in after else None, reporter) for i in wave]
            if scheduler is not None:
                _run_dask(batch, scheduler, done)
            elif n <= 1 or len(batch) == 1:
                for task in batch:
                    done(run_point(replace(task, workers=here)))
            else:
                _run_local(batch, min(n, len(batch)), done)
        result = SweepResult(out, record, time.perf_counter() - t0)
        atomic_write_text(out / ROWS, result.csv_text())
        if report:
            from piezopreload.reports.sweep_report import render_sweep_report

            with Pool(here) as pool:
                render_sweep_report(out, record, say=reporter.say, pool=pool)
    seconds = time.perf_counter() - t0
    result = SweepResult(out, record, seconds)
    reporter.write(_closing_line(result, seconds, report) + "\n")
    return result


def _closing_line(result: SweepResult, seconds: float, report: bool) -> str:
    """The sweep's last line on the console: the points done of all, the ``seconds`` taken, the failed ones, the ones
    that missed a requirement (by folder), where the rows are and, where ``report``, the report."""
    total, failed, missed = len(result.points), len(result.failed), result.missed
    missing = (f", {len(missed)} of them missed a requirement ({', '.join(Path(p.folder).name for p in missed)}: "
               "see requirements_missed in its row)" if missed else "")
    return (f"{total - failed} of {total} points done in {seconds:.1f} s"
            f"{f', {failed} failed' if failed else ''}{missing}; rows in {result.out / ROWS}"
            + (f", report {result.out / 'report.pdf'}" if report else ""))


def is_sweep_folder(out: str | Path) -> bool:
    """Whether ``out`` holds a sweep (its ``sweep.json``) rather than one study's outputs."""
    return (Path(out) / RECORD).is_file()


@dataclass(frozen=True)
class SweepReport:
    """A sweep's report typeset again (:func:`rerender_sweep_report`): the sweep's folder, the PDF, the time taken
    and the sweep's points."""

    out: Path
    report: Path
    seconds: float
    points: int

    def to_dict(self) -> dict[str, Any]:
        return {"out": str(self.out), "report": str(self.report), "seconds": self.seconds, "points": self.points}


def rerender_sweep_report(out: str | Path, progress: ProgressLike | None = None,
                          template: str | Path | None = None, workers: int | None = None) -> SweepReport:
    """Typeset a sweep's report again from ``OUT/sweep.json`` (``piezopreload report SWEEP_DIR``); nothing else runs.
    ``workers``: the processes that draw the figures (default: :func:`~piezopreload.core.parallel.default_workers`)."""
    reporter = as_progress(progress)
    t0 = time.perf_counter()
    out = Path(out)
    text = read_template(template)
    record = SweepRecord.load(out / RECORD)
    from piezopreload.reports.sweep_report import render_sweep_report

    with locked(out, f"{out}: a sweep is writing this folder; wait for it"), \
            Pool(default_workers() if workers is None else workers) as pool:
        written = render_sweep_report(out, record, say=reporter.say, template=text, pool=pool)
    seconds = time.perf_counter() - t0
    reporter.write(f"the sweep's report is {written['report']} ({seconds:.1f} s)\n")
    return SweepReport(out.resolve(), written["report"].resolve(), seconds, len(record.points))


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepResult:
    """A sweep's outcome: its folder and record; one row per point (:attr:`rows`), as CSV,
    JSON, a data frame, a plot.

    Parameters
    ----------
    out : Path
        The sweep's folder.
    record : SweepRecord
        Its record (``sweep.json``): the study, the axes, each point's values, status and figures.
    seconds : float or None
        The wall-clock time the sweep took (s; None: read back from its folder).
    """

    out: Path
    record: SweepRecord
    seconds: float | None = None

    @classmethod
    def load(cls, out: str | Path) -> SweepResult:
        """The sweep in ``out`` as its ``sweep.json`` records it.

        Parameters
        ----------
        out : str or Path
            The sweep's folder (the one holding ``sweep.json``).

        Returns
        -------
        SweepResult
            The sweep as recorded: its axes, points and figures.
        """
        return cls(Path(out), SweepRecord.load(Path(out) / RECORD))

    @property
    def rows(self) -> list[dict[str, Any]]:
        """One row per point: index, folder, swept values, status, error and figures (:meth:`SweepPoint.row`)."""
        return self.record.rows()

    @property
    def keys(self) -> tuple[str, ...]:
        """The swept keys."""
        return self.record.keys

    @property
    def points(self) -> tuple[SweepPoint, ...]:
        """Every point of the sweep, in order."""
        return self.record.points

    @property
    def failed(self) -> list[SweepPoint]:
        """The points whose run failed (status ``failed``)."""
        return [p for p in self.record.points if p.status == "failed"]

    @property
    def missed(self) -> list[SweepPoint]:
        """The points that ran but missed a requirement of their study."""
        return [p for p in self.record.points if p.status == "done" and p.figures.requirements_met is False]

    @property
    def exit_code(self) -> int:
        """5 where a point failed, else 4 where a point missed a requirement (as ``run``), else 0."""
        return EXIT_POINT_FAILED if self.failed else EXIT_REQUIREMENT_MISSED if self.missed else 0

    def folder(self, index: int) -> Path:
        """The folder of point ``index`` (its study outputs).

        Parameters
        ----------
        index : int
            The point's index, from 0.

        Returns
        -------
        Path
            The point's folder under the sweep's.
        """
        return self.out / self.record.points[index].folder

    def csv_text(self) -> str:
        """The rows as CSV (a list of missed requirements as their names separated by semicolons; None as an empty
        cell).

        Returns
        -------
        str
            A header of the columns and one line per point.
        """
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        columns = self.record.columns()
        writer.writerow(columns)
        for row in self.rows:
            writer.writerow(["" if row[c] is None
                             else "; ".join(r["name"] for r in row[c]) if c == "requirements_missed"
                             else row[c] for c in columns])
        return buf.getvalue()

    def to_dict(self) -> dict[str, Any]:
        """What ``sweep --json`` prints.

        Returns
        -------
        dict
            ``out``, ``study`` (name, path, hash), ``mode``, ``axes``, the counts of ``points``, ``done``, ``failed``
            and ``missed_requirements``, ``columns``, ``rows``, the CSV's and the report's paths (None where no report),
            ``seconds`` (the total and each point's) and ``exit_code``.
        """
        r = self.record
        return {"out": str(self.out), "study": {"name": r.study_name, "path": r.study_path, "sha256": r.study_sha256},
                "mode": r.mode, "axes": [a.to_dict() for a in r.axes], "points": len(r.points),
                "done": sum(p.status == "done" for p in r.points), "failed": len(self.failed),
                "missed_requirements": len(self.missed),
                "columns": list(r.columns()), "rows": self.rows, "csv": str(self.out / ROWS),
                "report": str(self.out / "report.pdf") if (self.out / "report.pdf").is_file() else None,
                "seconds": {"total": self.seconds, "points": {p.folder: p.seconds for p in r.points}},
                "exit_code": self.exit_code}

    def to_dataframe(self) -> Any:
        """The rows as a :class:`pandas.DataFrame` (pandas is not a dependency: install it to use this).

        Returns
        -------
        pandas.DataFrame
            One row per point, the columns in the sweep's order.

        Raises
        ------
        InputError
            Where pandas is not installed.
        """
        try:
            import pandas as pd
        except ImportError:
            raise InputError("SweepResult.to_dataframe needs pandas, which piezopreload does not install: "
                             "pip install pandas (or use .rows, or the CSV)") from None
        return pd.DataFrame(self.rows, columns=list(self.record.columns()))

    def plot(self, x: str | None = None, y: str | Sequence[str] = "worst_settling_s", *,
             by: str | Sequence[str] | None = None) -> Figure:
        """A figure of ``y`` (a column, or several: one panel each) against ``x`` (default: the first swept key),
        one line per value of ``by`` (default: the other swept keys of a grid); failed points marked.

        Parameters
        ----------
        x : str or None
            The column on the horizontal axis (None: the first swept key).
        y : str or sequence of str
            The column (or columns, one panel each) on the vertical axis.
        by : str, sequence of str or None
            The columns whose values each get a line (None: a grid's other swept keys; a list sweep's none).

        Returns
        -------
        matplotlib.figure.Figure
            The figure.

        Raises
        ------
        InputError
            Where a column named is not one of the sweep's.
        """
        x = x or self.keys[0]
        ys = [y] if isinstance(y, str) else list(y)
        if by is None:
            groups = [k for k in self.keys if k != x] if self.record.mode == "grid" else []
        else:
            groups = [by] if isinstance(by, str) else list(by)
        columns = self.record.columns()
        unknown = [c for c in (x, *ys, *groups) if c not in columns]
        if unknown:
            raise InputError(f"SweepResult.plot: no column '{unknown[0]}'; the columns are {', '.join(columns)}")
        from piezopreload.reports.sweep_figures import sweep_plot

        return sweep_plot(self.rows, x, ys, groups, title=f"sweep of {self.record.study_name}")

    def _table(self) -> tuple[list[str], list[list[str]]]:
        figures = [c for c in ("gain_set_status", "Kc_V_per_N", "Ti_s", "worst_settling_s", "worst_overshoot_N",
                               "tracking_rms_pct_of_range", "rigidity_min_cutting_N_per_um", "requirements_met")
                   if any(row[c] is not None for row in self.rows)]
        header = ["point", *self.keys, "status", *figures]
        body = [[str(row["point"]), *(str(row[k]) for k in self.keys), row["status"],
                 *(_cell(row[c]) for c in figures)] for row in self.rows]
        return header, body

    def __repr__(self) -> str:
        header, body = self._table()
        widths = [max(len(h), *(len(r[i]) for r in body)) if body else len(h) for i, h in enumerate(header)]
        lines = [f"SweepResult({self.record.study_name}, {len(body)} points, {self.record.mode}, "
                 f"{len(self.failed)} failed, {self.out})", "  ".join(h.rjust(w) for h, w in zip(header, widths))]
        lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in body]
        lines += [f"  p{p.index:03d} failed: {p.error}" for p in self.failed]
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        from html import escape

        header, body = self._table()
        head = "".join(f"<th>{escape(h)}</th>" for h in header)
        rows = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in r) + "</tr>" for r in body)
        errors = "".join(f"<li>p{p.index:03d}: {escape(p.error or '')}</li>" for p in self.failed)
        return (f"<p><b>Sweep of {escape(self.record.study_name)}</b>: {len(body)} points ({self.record.mode}), "
                f"{len(self.failed)} failed; <code>{escape(str(self.out))}</code></p>"
                f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"
                + (f"<ul>{errors}</ul>" if errors else ""))


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)
