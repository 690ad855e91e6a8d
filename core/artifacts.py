"""Versioned JSON artifacts: written atomically, read back with every field checked.

Every artifact is ``{"schema": "piezopreload/<kind>/1", "package_version": ..., "created_utc":
..., "inputs": {...hashes...}, "units": {...}, ...}``. Readers reject an unknown schema, the wrong
kind, missing fields and non-finite numbers, naming the field.
"""

from __future__ import annotations

import datetime as _dt
import functools
import hashlib
import json
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from piezopreload.core.errors import ArtifactError

__all__ = ["ArtifactError", "ArtifactKind", "Kinds", "DOCUMENTS", "STUDY_RUN", "REPORT", "SWEEP_REPORT",
           "schema_name", "write_artifact", "read_artifact", "atomic_write_text", "atomic_write_bytes", "content_hash",
           "parse_artifact", "package_version", "read_bytes", "finite_or_none", "artifact_kind"]

VERSION = 1
HASH_FIELD = "content_sha256"


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of artifact: its name, the fields its documents hold at their top level, whether they carry their
    content's hash, what writes one again.

    A record declares its own (:meth:`piezopreload.core.records.Artifact.kind`); the documents no record
    declares yet are the constants below. Readers and writers take the kind itself, so nothing here is looked up in
    a table filled as modules are imported; the one list of every kind is
    :data:`piezopreload.artifacts.registry.KINDS`.

    Parameters
    ----------
    name : str
        The kind (``gain-set``), the middle of its schema's name.
    fields : callable
        ``fields()``: the fields a document of the kind must hold at its top level (computed when asked, when
        every type they name exists).
    hashed : bool
        Whether its documents carry their content's hash (``content_sha256``), checked on every read.
    again : str
        What writes a document of the kind again, the end of every message about one.
    owner : str
        The type or document that declares it.
    """

    name: str
    fields: Callable[[], tuple[str, ...]]
    hashed: bool = False
    again: str = ""
    owner: str = ""

    def required(self) -> tuple[str, ...]:
        """The fields a document of the kind must hold at its top level.

        Returns
        -------
        tuple of str
            Their names.
        """
        return tuple(self.fields())


def _undeclared(name: str, *fields: str) -> ArtifactKind:
    return ArtifactKind(name, functools.partial(tuple, fields), owner=f"the {name} document")


# The documents whose writers do not declare them on a record yet (the study run's manifest, the two
# reports): their required fields, here until a record declares each.
STUDY_RUN = _undeclared("study-run", "study", "stages")
REPORT = _undeclared("report", "title", "verdicts", "summary", "sections", "appendix", "figures")
SWEEP_REPORT = _undeclared("sweep-report", "title", "summary", "table", "figures", "provenance")
#: the kinds declared here rather than by a record
DOCUMENTS = (STUDY_RUN, REPORT, SWEEP_REPORT)


class Kinds(Mapping[str, tuple[str, ...]]):
    """Artifact kinds by name, each to the fields its documents must hold: made once from a list of kinds (a name
    given twice is refused), never added to.

    Parameters
    ----------
    kinds : iterable of ArtifactKind
        The kinds.
    """

    def __init__(self, kinds: Iterable[ArtifactKind]) -> None:
        known: dict[str, ArtifactKind] = {}
        for kind in kinds:
            if kind.name in known:
                raise ValueError(f"artifact kind '{kind.name}' is declared twice: by {known[kind.name].owner} and by "
                                 f"{kind.owner}")
            known[kind.name] = kind
        self._kinds = known

    def kind(self, name: str) -> ArtifactKind:
        """The kind called ``name``.

        Parameters
        ----------
        name : str
            Its name (``gain-set``).

        Returns
        -------
        ArtifactKind
            Its declaration.

        Raises
        ------
        ValueError
            Where no kind has that name, naming the kinds there are.
        """
        if name not in self._kinds:
            raise ValueError(f"unknown artifact kind {name!r}; the kinds known are {', '.join(self)}")
        return self._kinds[name]

    def __getitem__(self, name: str) -> tuple[str, ...]:
        return self._kinds[name].required()

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._kinds))

    def __len__(self) -> int:
        return len(self._kinds)

    def __repr__(self) -> str:
        return "Kinds(" + ", ".join(f"{k}: {self[k]}" for k in self) + ")"


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


def write_artifact(path: str | Path, declared: ArtifactKind, body: dict[str, Any]) -> dict[str, Any]:
    """Write an artifact of the kind ``declared`` holding ``body`` atomically; returns the whole document."""
    kind = declared.name
    doc = {
        "schema": schema_name(kind),
        "package_version": package_version(),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        **body,
    }
    missing = [f for f in declared.required() if f not in doc]
    if missing:
        raise ValueError(f"a {kind} artifact needs the field '{missing[0]}'")
    bad = _first_non_finite(doc, "")
    if bad is not None:
        raise ValueError(f"{kind} artifact field '{bad.lstrip('.')}' is not finite")
    if declared.hashed:
        doc.pop(HASH_FIELD, None)
        doc[HASH_FIELD] = content_hash(doc)
    atomic_write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")
    return doc


def field_message(shown: str, path: str, problem: str, again: str = "") -> str:
    """The one format of a reader's message: the file, the field's path, what is wrong, how to write the file again.

    Parameters
    ----------
    shown : str
        The file (or what stands for it: "the gain set").
    path : str
        The field's path in the document (``gains.Ti_s``, ``fronts[0].pair``; "" for the document itself).
    problem : str
        What is wrong, as a sentence's predicate: ``is missing; expected a finite number``, ``must be WHAT, got
        VALUE``, ``is not valid: WHY``.
    again : str
        What writes the file again ("" where nothing does).

    Returns
    -------
    str
        ``FILE: field 'PATH' PROBLEM; AGAIN``.

    Examples
    --------
    >>> field_message("gains.json", "gains.Ti_s", "is missing; expected a finite number > 0", "run the tune stage")
    "gains.json: field 'gains.Ti_s' is missing; expected a finite number > 0; run the tune stage"
    """
    head = f"{shown}: field '{path}' {problem}" if path else f"{shown} {problem}"
    return head + (f"; {again}" if again else "")


def read_artifact(path: str | Path, kind: ArtifactKind, *, fields: bool = True) -> dict[str, Any]:
    """Read and check a ``kind`` artifact: its JSON, schema, finite numbers, a hashed kind's hash and, where
    ``fields``, the fields its kind requires.

    Parameters
    ----------
    path : str or Path
        The file.
    kind : ArtifactKind
        The kind it must be.
    fields : bool
        Whether to check its kind's required fields (a record's own reader, which checks every field, passes
        False).

    Returns
    -------
    dict
        The document.

    Raises
    ------
    ArtifactError
        Naming the file, the field and what was expected.
    """
    shown = str(path)
    raw = read_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ArtifactError(f"{shown}: cannot read ({exc})") from None
    return parse_artifact(text, kind, shown, fields=fields)


def artifact_kind(path: str | Path) -> str:
    """The kind an artifact's ``schema`` names, for a reader that takes more than one.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    str
        Its kind (``gain-set``, ``tuning``, ...).

    Raises
    ------
    ArtifactError
        Naming the file where it is not an artifact of this package.
    """
    shown = str(path)
    try:
        text = read_bytes(path).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ArtifactError(f"{shown}: cannot read ({exc})") from None
    schema = _json_object(text, shown).get("schema")
    kind = schema.split("/")[1] if isinstance(schema, str) and schema.count("/") == 2 else None
    if not (isinstance(schema, str) and schema.startswith("piezopreload/") and kind):
        raise ArtifactError(field_message(shown, "schema", f"must name a piezopreload artifact (piezopreload/KIND/"
                                                           f"{VERSION}), got {schema!r}"))
    return str(kind)


def _json_object(text: str, shown: str) -> dict[str, Any]:
    """The JSON object ``text`` holds; :class:`ArtifactError` when it is not JSON or not an object."""
    try:
        doc = json.loads(text)  # NaN and Infinity parse to floats; _first_non_finite names them
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{shown}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(doc, dict):
        raise ArtifactError(field_message(shown, "", f"must be a JSON object, got {type(doc).__name__}"))
    return doc


def _check_schema(doc: dict[str, Any], declared: ArtifactKind, shown: str) -> None:
    """The document's ``schema`` must be this version's schema of ``declared``."""
    kind = declared.name
    schema = doc.get("schema")
    expected = schema_name(kind)
    if schema == expected:
        return
    got_kind = schema.split("/")[1] if isinstance(schema, str) and schema.count("/") == 2 else None
    why = ("" if not isinstance(schema, str) or not schema.startswith("piezopreload/") or got_kind is None
           else f" (a '{got_kind}' artifact)" if got_kind != kind
           else " (a version of the kind this version of the package does not read)")
    raise ArtifactError(field_message(shown, "schema", f"must be '{expected}', got {schema!r}{why}", declared.again))


def _check_fields(doc: dict[str, Any], declared: ArtifactKind, shown: str, fields: bool) -> None:
    """Every field a ``declared`` kind needs is there (where ``fields``), and every number is finite."""
    kind, again = declared.name, declared.again
    required = declared.required() if fields else ()
    for name in required:
        if name not in doc:
            raise ArtifactError(field_message(shown, name, f"is missing; a {kind} artifact holds "
                                                           f"{', '.join(required)}", again))
    bad = _first_non_finite(doc, "")
    if bad is not None:
        value = _value_at(doc, bad)
        raise ArtifactError(field_message(shown, bad.lstrip("."), f"must be a finite number, got {value!r}",
                                          again))


def _value_at(doc: Any, path: str) -> Any:
    for key in re.findall(r"\.([^.\[]+)|\[(\d+)\]", path):
        doc = doc[key[0]] if key[0] else doc[int(key[1])]
    return doc


def _check_hash(doc: dict[str, Any], declared: ArtifactKind, shown: str) -> None:
    """A hashed kind carries the hash of its content as it was written."""
    kind, again = declared.name, declared.again
    stored = doc.get(HASH_FIELD)
    if not isinstance(stored, str):
        raise ArtifactError(field_message(shown, HASH_FIELD, f"is missing; expected the hash a {kind} artifact is "
                                                             "written with", again))
    if stored != content_hash(doc):
        raise ArtifactError(field_message(shown, HASH_FIELD, "does not match the content: the file was changed after "
                                                             "it was written", again))


def parse_artifact(text: str, kind: ArtifactKind, shown: str = "the document", *,
                   fields: bool = True) -> dict[str, Any]:
    """:func:`read_artifact` on a document's text (pushed over a network, say).

    Parameters
    ----------
    text : str
        The document's text.
    kind : ArtifactKind
        The kind it must be.
    shown : str
        What the messages call it.
    fields : bool
        Whether to check its kind's required fields (False for a record's own reader).

    Returns
    -------
    dict
        The document.
    """
    doc = _json_object(text, shown)
    _check_schema(doc, kind, shown)
    _check_fields(doc, kind, shown, fields)
    if kind.hashed:
        _check_hash(doc, kind, shown)
    return doc


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or None where it is not finite (an artifact holds finite numbers only)."""
    return float(x) if math.isfinite(x) else None
