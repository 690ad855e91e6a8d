"""A content-addressed store of stage outputs that several output folders share.

Two folders that run a stage with the same key (:func:`piezopreload.core.stages.content_key`: the
same inputs, the same code) would compute the same outputs. A :class:`StageCache` keeps a stage's
outputs once, under its key: ``ROOT/<key[:2]>/<key>/`` holds the files, at their paths relative to
the folder that wrote them, and ``entry.json`` (an artifact of kind ``stage-cache``,
:class:`CacheEntry`: the stage's name, its summary and each output's path and SHA-256).

:meth:`StageCache.run` restores a stage from the store into a folder, or computes it there and
stores what it wrote. A lock per key (``flock`` on ``ROOT/<key[:2]>/<key>.lock``) makes a second
process that wants the same key wait for the first and then restore its outputs, so a stage is
computed once however many folders need it at the same time; a process holds one key's lock at a
time, so no two wait on each other. An entry is written into a private folder and renamed into
place, whole or not at all; an entry whose files no longer hash as recorded is dropped and the
stage computed again. A stage that fails stores nothing.

The store knows nothing of studies: a stage is a name, a key and a function that computes it.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar

from piezopreload.core.artifacts import ArtifactError, atomic_write_bytes
from piezopreload.core.records import Artifact, Invalid, entry, record
from piezopreload.core.stages import sha256_file

__all__ = ["StageCache", "CacheEntry", "KIND"]

KIND = "stage-cache"
_ENTRY = "entry.json"
_FILES = "files"
_INCOMING = ".incoming"  # entries being written, renamed into place when whole


def _outputs(doc: Any) -> dict[str, dict[str, str]]:
    """Each output's label and its ``path`` and ``sha256``."""
    if not isinstance(doc, dict):
        raise ValueError(f"expected an object of outputs, got {type(doc).__name__}")
    out = {}
    for label, o in doc.items():
        if not isinstance(o, dict) or not isinstance(o.get("path"), str) or not isinstance(o.get("sha256"), str):
            raise Invalid(label, f"must be an object of 'path' and 'sha256' (strings), got {o!r}")
        out[str(label)] = {"path": o["path"], "sha256": o["sha256"]}
    return out


@record
class CacheEntry(Artifact):
    """One stored stage: its name, its key, its summary and its outputs."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the cache entry"

    stage: str = entry("The stage's name.")
    key: str = entry("Its content key (64 hex digits).")
    summary: dict[str, Any] = entry("Its summary, as its record in a run's manifest holds it.")
    outputs: dict[str, dict[str, str]] = entry("Each output's label: its ``path`` (relative to the folder that wrote "
                                               "it) and ``sha256``.", read=_outputs,
                                               takes="an object of outputs (path, sha256)")

    def __post_init__(self) -> None:
        if not self.stage or len(self.key) != 64:
            raise ValueError("CacheEntry: a stage name and a 64-digit key are needed, "
                             f"got {self.stage!r}, {self.key!r}")
        for label, o in self.outputs.items():
            path = Path(o.get("path", ""))
            if not o.get("path") or path.is_absolute() or ".." in path.parts or len(o.get("sha256", "")) != 64:
                raise ValueError(f"CacheEntry: output '{label}' needs a relative path inside its folder and a SHA-256, "
                                 f"got {o!r}")

    def save(self, path: Path) -> None:
        """Write the entry atomically.

        Parameters
        ----------
        path : Path
            The file.
        """
        self._write(path)


class StageCache:
    """Stage outputs by content key under ``root`` (see the module docstring).

    ``reused`` lists the stages this object restored rather than computed, in order.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.reused: list[str] = []

    def __repr__(self) -> str:
        return f"StageCache({str(self.root)!r})"

    def folder(self, key: str) -> Path:
        """Where the entry of ``key`` lives."""
        return self.root / key[:2] / key

    def stored(self) -> list[str]:
        """The keys stored, sorted."""
        return sorted(p.parent.name for p in self.root.glob(f"??/*/{_ENTRY}"))

    def entry(self, key: str) -> CacheEntry | None:
        """The stored entry of ``key``, or None (also for an unreadable one)."""
        try:
            return CacheEntry.load(self.folder(key) / _ENTRY)
        except (OSError, ArtifactError):
            return None

    def clean(self, *, everything: bool = False) -> None:
        """Remove what a killed process left half-stored (``everything``: the whole store). Only while no other
        process uses the store."""
        shutil.rmtree(self.root if everything else self.root / _INCOMING, ignore_errors=True)

    def run(self, stage: str, key: str, out: Path, compute: Callable[[], tuple[dict[str, Path], dict[str, Any]]], *,
            refresh: bool = False, say: Callable[[str], None] | None = None) -> tuple[dict[str, Path], dict[str, Any]]:
        """The outputs (label -> path in ``out``) and summary of ``stage`` with ``key``: restored into ``out`` from
        the store, or computed by ``compute`` (which writes into ``out``) and stored. ``refresh`` computes again
        and replaces the entry. A failure of ``compute`` propagates and stores nothing."""
        with self._lock(key):
            if not refresh:
                hit = self.restore(key, out)
                if hit is not None:
                    self.reused.append(stage)
                    if say is not None:
                        say(f"reused the outputs of an identical stage (key {key[:12]}) from {self.root}")
                    return hit
            outputs, summary = compute()
            try:
                self._store(stage, key, Path(out), outputs, summary)
            except (OSError, ArtifactError, ValueError) as exc:  # the stage is done; only the sharing is lost
                if say is not None:
                    say(f"warning: could not keep the outputs in {self.root} ({exc}); other folders compute them again")
            return outputs, summary

    def restore(self, key: str, out: Path) -> tuple[dict[str, Path], dict[str, Any]] | None:
        """Copy the entry of ``key`` into ``out`` (files already there with the right hash are kept); None when there
        is no intact entry (a damaged one is dropped)."""
        entry = self.entry(key)
        if entry is None:
            return None
        src = self.folder(key) / _FILES
        for o in entry.outputs.values():
            if not (src / o["path"]).is_file() or sha256_file(src / o["path"]) != o["sha256"]:
                shutil.rmtree(self.folder(key), ignore_errors=True)
                return None
        outputs: dict[str, Path] = {}
        for label, o in entry.outputs.items():
            dest = Path(out) / o["path"]
            if not (dest.is_file() and sha256_file(dest) == o["sha256"]):
                atomic_write_bytes(dest, (src / o["path"]).read_bytes())
            outputs[label] = dest
        return outputs, entry.summary

    def _store(self, stage: str, key: str, out: Path, outputs: dict[str, Path], summary: dict[str, Any]) -> None:
        root = out.resolve()
        recorded = {}
        for label, path in outputs.items():
            if Path(path).is_file():  # as the stage's record lists them: the files that exist
                recorded[label] = {"path": Path(path).resolve().relative_to(root).as_posix(),
                                   "sha256": sha256_file(path)}
        entry = CacheEntry(stage, key, summary, recorded)
        tmp = self.root / _INCOMING / f"{key}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        try:
            for o in recorded.values():
                (tmp / _FILES / o["path"]).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(root / o["path"], tmp / _FILES / o["path"])
            entry.save(tmp / _ENTRY)
            final = self.folder(key)
            if final.exists():  # refresh: the old entry goes (the lock is held, so no one reads it)
                shutil.rmtree(final)
            final.parent.mkdir(parents=True, exist_ok=True)
            os.rename(tmp, final)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    @contextmanager
    def _lock(self, key: str) -> Iterator[None]:
        """Hold the lock of ``key``, waiting for a process that holds it (where ``flock`` exists)."""
        path = self.root / key[:2] / f"{key}.lock"
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no sharing between processes at once
            yield
            return
        with open(path, "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)
