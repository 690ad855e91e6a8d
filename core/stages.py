"""Content-keyed stages: run a list of stages into a folder, skipping those whose key and outputs are unchanged.

The machinery knows nothing of studies. A stage is anything with a ``name`` and a ``what`` (a
line saying what it does); the caller says how to key it, whether it applies, how to run it
(returning its outputs, label -> path, and a summary) and how to save the records. Each stage's
record (``status``, ``key``, ``seconds``, ``finished_utc``, ``summary``, ``outputs`` with their
paths relative to the folder and their SHA-256) is what a manifest keeps; a stage whose key is
the recorded one and whose outputs still hash as recorded is not run again.

A key is the SHA-256 of a JSON body (:func:`content_key`) the caller assembles from what the
stage reads: its inputs' hashes (:func:`upstream_hashes`, :func:`sha256_file`) and the source of
the code it runs (:func:`code_hash`).
"""

from __future__ import annotations

import hashlib
import importlib
import json
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from piezopreload.core.errors import InputError, InternalError
from piezopreload.core.progress import ProgressLike, as_progress

__all__ = ["StageFailed", "StageCrashed", "Partial", "StageLike", "StageOutcome", "sha256_file",
           "code_hash", "content_key", "upstream_hashes", "outputs_intact", "record_outputs", "utc", "locked",
           "run_stages"]


class StageFailed(InputError):
    """A stage that could not complete: the message names it; ``exit_code`` is what the CLI returns."""

    def __init__(self, stage: str, message: str, exit_code: int = 2) -> None:
        super().__init__(f"stage '{stage}' failed: {message}")
        self.stage = stage
        self.exit_code = exit_code


class StageCrashed(InternalError):
    """An internal failure inside a stage (exit code 1); the cause is chained."""


class Partial(Exception):
    """Carries what a failing stage wrote, so the manifest can list it (raise the failure ``from Partial(...)``),
    and, where it has one, the failed stage's summary (a tripped rig run's trip)."""

    def __init__(self, outputs: dict[str, Path], summary: dict[str, Any] | None = None) -> None:
        super().__init__("partial outputs")
        self.outputs = outputs
        self.summary = summary


class StageLike(Protocol):
    """What the runner needs of a stage: its name and a line saying what it does."""

    @property
    def name(self) -> str: ...

    @property
    def what(self) -> str: ...


S = TypeVar("S", bound=StageLike)


@dataclass(frozen=True)
class StageOutcome:
    """One stage of a run: whether it ran, its status (``done``, ``up to date``, ``not applicable``), its time."""

    stage: str
    ran: bool
    status: str
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "ran": self.ran, "status": self.status, "seconds": self.seconds}


def sha256_file(path: Path) -> str:
    """SHA-256 (hex) of a file's bytes, read in blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


_CODE_HASHES: dict[str, str] = {}


def code_hash(modules: tuple[str, ...]) -> str:
    """SHA-256 of the source (``.py``, ``.typ``) of the named packages, in order (cached per process)."""
    key = ",".join(modules)
    if key not in _CODE_HASHES:
        h = hashlib.sha256()
        for name in modules:
            root = Path(importlib.import_module(name).__file__ or "").parent
            real = root.resolve()  # the package's own files: not a subpackage linked into it (piezopreload/core)
            for path in sorted(p for p in root.rglob("*")
                               if p.suffix in (".py", ".typ") and "__pycache__" not in p.parts
                               and p.resolve().is_relative_to(real)):
                h.update(f"{name}/{path.relative_to(root).as_posix()}\n".encode())
                h.update(path.read_bytes())
        _CODE_HASHES[key] = h.hexdigest()
    return _CODE_HASHES[key]


def content_key(body: dict[str, Any]) -> str:
    """SHA-256 of ``body`` as canonical JSON (sorted keys, no spaces; ``str`` for what JSON lacks)."""
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


def upstream_hashes(needs: tuple[str, ...], records: dict[str, dict[str, Any]]
                    ) -> dict[str, dict[str, str] | str | None]:
    """For each stage read: its outputs' hashes where it is done, else its status (None if it never ran)."""
    upstream: dict[str, dict[str, str] | str | None] = {}
    for name in needs:
        rec = records.get(name, {})
        upstream[name] = ({label: o["sha256"] for label, o in rec.get("outputs", {}).items()}
                          if rec.get("status") == "done" else rec.get("status"))
    return upstream


def outputs_intact(out: Path, record: dict[str, Any]) -> bool:
    """Whether every output a record lists is still in ``out`` with the hash recorded."""
    for o in record.get("outputs", {}).values():
        path = out / o["path"]
        if not path.is_file() or sha256_file(path) != o["sha256"]:
            return False
    return True


def record_outputs(out: Path, outputs: dict[str, Path]) -> dict[str, dict[str, str]]:
    """The record of a stage's outputs: label -> path relative to ``out`` and SHA-256 (files that exist)."""
    root = out.resolve()
    return {label: {"path": Path(p).resolve().relative_to(root).as_posix(), "sha256": sha256_file(p)}
            for label, p in outputs.items() if p.is_file()}


def utc() -> str:
    """Now, UTC, ``YYYY-MM-DDTHH:MM:SSZ``."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


@contextmanager
def locked(out: Path, busy: str) -> Iterator[None]:
    """One writer at a time per folder (advisory lock on ``out/.lock``, where flock exists).

    ``busy``: the message of the :class:`InputError` raised when another process holds it.
    """
    out.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(out / ".lock", "w") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputError(busy) from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def run_stages(stages: Sequence[S], records: dict[str, dict[str, Any]], out: Path, progress: ProgressLike, *,
               force: bool, key: Callable[[S], str], applies: Callable[[S], str | None],
               run: Callable[[S], tuple[dict[str, Path], dict[str, Any]]],
               save: Callable[[], None]) -> list[StageOutcome]:
    """Run ``stages`` in order into ``out``, updating ``records`` (and calling ``save``) after each.

    A stage that does not apply (``applies`` gives a reason) is recorded as such; one whose key and
    outputs are unchanged is not run again unless ``force``. A failing stage is recorded with
    what it wrote (a :class:`Partial` as the failure's cause) and stops the run: an
    :class:`InputError` as a :class:`StageFailed` naming it, anything else as a :class:`StageCrashed`.
    Returns one :class:`StageOutcome` per stage.
    """
    progress = as_progress(progress)
    done: list[StageOutcome] = []
    for i, stage in enumerate(stages, start=1):
        reason = applies(stage)
        stage_key = key(stage)
        old = records.get(stage.name)
        if reason is not None:
            progress.stage(i, len(stages), stage.name, f"not applicable ({reason})")
            records[stage.name] = {"status": "not applicable", "reason": reason, "key": stage_key, "outputs": {}}
            done.append(StageOutcome(stage.name, False, "not applicable", 0.0))
            continue
        if not force and old is not None and old.get("status") == "done" and old.get("key") == stage_key \
                and outputs_intact(out, old):
            progress.stage(i, len(stages), stage.name, "up to date, not run again")
            done.append(StageOutcome(stage.name, False, "up to date", 0.0))
            continue
        progress.stage(i, len(stages), stage.name, stage.what)
        t0 = time.perf_counter()
        try:
            outputs, summary = run(stage)
        except Exception as exc:
            partial = exc.__cause__.outputs if isinstance(exc.__cause__, Partial) else {}
            message = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
            records[stage.name] = {"status": "failed", "key": stage_key, "message": message,
                                   "seconds": time.perf_counter() - t0, "finished_utc": utc(),
                                   "outputs": record_outputs(out, partial)}
            if isinstance(exc.__cause__, Partial) and exc.__cause__.summary is not None:
                records[stage.name]["summary"] = exc.__cause__.summary
            save()
            if isinstance(exc, StageFailed):
                raise
            if isinstance(exc, InputError):
                raise StageFailed(stage.name, str(exc)) from exc
            raise StageCrashed(f"stage '{stage.name}' failed: {type(exc).__name__}: {exc}") from exc
        seconds = time.perf_counter() - t0
        records[stage.name] = {"status": "done", "key": stage_key, "seconds": seconds, "finished_utc": utc(),
                               "summary": summary, "outputs": record_outputs(out, outputs)}
        save()
        progress.say(f"done in {seconds:.1f} s")
        done.append(StageOutcome(stage.name, True, "done", seconds))
    return done
