"""Versioned JSON artifacts: written atomically, read back with every field checked.

Every artifact is ``{"schema": "piezopreload/<kind>/1", "package_version": ..., "created_utc":
..., "inputs": {...hashes...}, "units": {...}, ...}``. Readers reject an unknown schema, the wrong
kind, missing fields and non-finite numbers, naming the field.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import tempfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from piezopreload.core.errors import ArtifactError

__all__ = ["ArtifactError", "schema_name", "write_artifact", "read_artifact", "atomic_write_text", "atomic_write_bytes",
           "content_hash", "parse_artifact", "package_version", "read_bytes", "finite_or_none",
           "artifact_kind"]

VERSION = 1
KINDS = {
    "hysteresis-model": ("model", "units", "inputs"),
    "gain-set": ("gains", "status", "inputs"),
    "design": ("optimum", "fronts", "schedule", "inputs", "units"),
    "rig-run": ("status", "events", "gain_set_sha256", "backend", "csv", "summary"),
    "tuning": ("gains", "table", "criteria", "inputs"),
    "validation": ("gain_set_sha256", "passed", "metrics", "inputs"),
    "responses": ("runs", "reproduction", "inputs"),
    "study-run": ("study", "stages"),
    "report": ("title", "verdicts", "summary", "sections", "appendix", "figures"),
    "plant": ("rig", "design_sha256", "inputs"),
    "system": ("tracking_rms_pct_of_range", "rigidity_min_cutting_N_per_um", "rigidity_ratio_min", "series",
               "inputs"),
    "learning": ("pass_records", "tracking_rms_N", "before_learning_rms_N", "history", "inputs"),
    "learned-signal": ("ff_extra_V", "setpoint_N", "sample_period_s", "reference", "reference_sha256",
                       "gain_set_sha256", "inputs"),
    "sweep": ("study", "mode", "axes", "points"),
    "sweep-report": ("title", "summary", "table", "figures", "provenance"),
    "stage-cache": ("stage", "key", "summary", "outputs"),
}
#: kinds whose documents carry ``content_sha256``, checked on every read
HASHED = {"gain-set", "learned-signal"}
HASH_FIELD = "content_sha256"
#: the command that writes a hashed kind again
_WRITER = {"learned-signal": "learn"}


def package_version() -> str:
    """The installed package's version (``0+unknown`` from a source tree that is not installed)."""
    try:
        return version("piezopreload")
    except PackageNotFoundError:
        return "0+unknown"


def read_bytes(path: str | Path, what: str = "file", error: type[Exception] = ArtifactError) -> bytes:
    """The bytes of an input file; a missing or unreadable file is ``error`` naming the path."""
    shown = str(path)
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise error(f"{shown}: no such {what}") from None
    except IsADirectoryError:
        raise error(f"{shown}: is a folder; expected a {what}") from None
    except OSError as exc:
        raise error(f"{shown}: cannot read ({exc.strerror or exc})") from None


def schema_name(kind: str) -> str:
    return f"piezopreload/{kind}/{VERSION}"


#: the process's umask, read once at import (reading it means setting it; imports run in one thread)
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: see :func:`atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, fsync and a rename.

    A reader sees the old file or the new one, never a part. The file gets the permissions a
    plain ``open(path, "w")`` would give it (mkstemp's own are 0600).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def content_hash(doc: dict[str, Any]) -> str:
    """SHA-256 of the document without its hash field, as canonical JSON (sorted keys, no spaces)."""
    body = {k: v for k, v in doc.items() if k != HASH_FIELD}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()).hexdigest()


def _first_non_finite(value: Any, where: str) -> str | None:
    """Path of the first non-finite number in a JSON-like value, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        found = _first_non_finite(item, f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]")
        if found is not None:
            return found
    return None


def write_artifact(path: str | Path, kind: str, body: dict[str, Any]) -> dict[str, Any]:
    """Write a ``kind`` artifact holding ``body`` atomically; returns the whole document."""
    if kind not in KINDS:
        raise ValueError(f"unknown artifact kind {kind!r}")
    doc = {
        "schema": schema_name(kind),
        "package_version": package_version(),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        **body,
    }
    missing = [f for f in KINDS[kind] if f not in doc]
    if missing:
        raise ValueError(f"a {kind} artifact needs the field '{missing[0]}'")
    bad = _first_non_finite(doc, "")
    if bad is not None:
        raise ValueError(f"{kind} artifact field '{bad.lstrip('.')}' is not finite")
    if kind in HASHED:
        doc.pop(HASH_FIELD, None)
        doc[HASH_FIELD] = content_hash(doc)
    atomic_write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")
    return doc


def read_artifact(path: str | Path, kind: str) -> dict[str, Any]:
    """Read and check a ``kind`` artifact; :class:`ArtifactError` names what is wrong and where."""
    shown = str(path)
    raw = read_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ArtifactError(f"{shown}: cannot read ({exc})") from None
    return parse_artifact(text, kind, shown)


def artifact_kind(path: str | Path) -> str:
    """The kind an artifact's ``schema`` names (``gain-set``, ``tuning``, ...), for a reader that takes more than
    one; :class:`ArtifactError` names the file where it is not an artifact of this package."""
    shown = str(path)
    try:
        text = read_bytes(path).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ArtifactError(f"{shown}: cannot read ({exc})") from None
    schema = _json_object(text, shown).get("schema")
    kind = schema.split("/")[1] if isinstance(schema, str) and schema.count("/") == 2 else None
    if not (isinstance(schema, str) and schema.startswith("piezopreload/") and kind in KINDS):
        raise ArtifactError(f"{shown}: field 'schema' is {schema!r}; expected a piezopreload artifact")
    return kind


def _json_object(text: str, shown: str) -> dict[str, Any]:
    """The JSON object ``text`` holds; :class:`ArtifactError` when it is not JSON or not an object."""
    try:
        doc = json.loads(text)  # NaN and Infinity parse to floats; _first_non_finite names them
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{shown}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(doc, dict):
        raise ArtifactError(f"{shown}: expected a JSON object at the top level")
    return doc


def _check_schema(doc: dict[str, Any], kind: str, shown: str) -> None:
    """The document's ``schema`` must be this version's schema of ``kind``."""
    schema = doc.get("schema")
    expected = schema_name(kind)
    if not isinstance(schema, str) or not schema.startswith("piezopreload/"):
        raise ArtifactError(f"{shown}: field 'schema' is {schema!r}; expected '{expected}'")
    if schema != expected:
        got_kind = schema.split("/")[1] if schema.count("/") == 2 else schema
        if got_kind != kind:
            raise ArtifactError(f"{shown}: this is a '{got_kind}' artifact; expected a '{kind}' ({expected})")
        raise ArtifactError(f"{shown}: schema '{schema}' is not supported by this version; expected '{expected}'")


def _check_fields(doc: dict[str, Any], kind: str, shown: str) -> None:
    """Every field a ``kind`` needs is there, and every number is finite."""
    for name in KINDS[kind]:
        if name not in doc:
            raise ArtifactError(f"{shown}: field '{name}' is missing")
    bad = _first_non_finite(doc, "")
    if bad is not None:
        raise ArtifactError(f"{shown}: field '{bad.lstrip('.')}' is not a finite number; "
                            "artifacts hold finite numbers only")


def _check_hash(doc: dict[str, Any], kind: str, shown: str) -> None:
    """A hashed ``kind`` carries the hash of its content as it was written."""
    stored = doc.get(HASH_FIELD)
    if not isinstance(stored, str):
        raise ArtifactError(f"{shown}: field '{HASH_FIELD}' is missing; "
                            f"a {kind} must carry the hash it was written with")
    if stored != content_hash(doc):
        raise ArtifactError(f"{shown}: the content does not match its '{HASH_FIELD}': the file was changed after it "
                            f"was written; regenerate it with 'piezopreload {_WRITER.get(kind, 'tune')}'")


def parse_artifact(text: str, kind: str, shown: str = "the document") -> dict[str, Any]:
    """:func:`read_artifact` on a document's text (pushed over a network, say); ``shown`` names it in errors."""
    doc = _json_object(text, shown)
    _check_schema(doc, kind, shown)
    _check_fields(doc, kind, shown)
    if kind in HASHED:
        _check_hash(doc, kind, shown)
    return doc


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or None where it is not finite (an artifact holds finite numbers only)."""
    return float(x) if math.isfinite(x) else None
