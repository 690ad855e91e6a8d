"""Each public name of the front door documents what it takes and what it gives, in numpydoc's sections.

After python-control's ``control/tests/docstrings_test.py``: a function's or a class's docstring
must have a ``Parameters`` section naming every parameter of its signature (and no parameter it
does not take), and a function that returns something a ``Returns`` section. The sections are
read by numpydoc's own parser, as the documentation site reads them.

As there, the check recurses into the classes: every public method (a classmethod and a staticmethod
among them) of every exported class is held to the same rule, and every public property has a
docstring (a property reads as an attribute, so it needs no ``Returns`` section). A method is checked
once, in the class that defines it: one inherited from a base class of this package is checked there,
one inherited from the standard library (``object``, ``Exception``) is not ours to document.

A record's ``Parameters`` section is written by :func:`piezopreload.core.records.record` from its
fields' declarations, so the signature check above cannot fail for it (the signature and the section
come from the same fields). Records are checked against their declaration instead: each field is in
the section, with the doc, the unit and the default of its ``entry(...)`` and the type of its
annotation as Python resolves it.
"""

import dataclasses
import inspect
import re
import sys
import types
import typing
from functools import cached_property

import numpy as np
import pytest
from numpydoc.docscrape import NumpyDocString

import piezopreload
from piezopreload.core.records import ENTRY, Record, entry, record

NAMES = [n for n in piezopreload.__all__ if callable(getattr(piezopreload, n))]
CLASSES = [n for n in NAMES if inspect.isclass(getattr(piezopreload, n))]
RECORDS = [n for n in CLASSES if issubclass(getattr(piezopreload, n), Record)
           and dataclasses.is_dataclass(getattr(piezopreload, n))]


def _ours(cls):
    """Whether ``cls`` is defined in this package (not the standard library's or numpy's)."""
    return cls.__module__.split(".")[0] == "piezopreload"


def _members():
    """Every public method and property of the exported classes, once, keyed by the class that defines it.

    Returns
    -------
    dict
        ``"Class.name"`` to ``(kind, object)``: kind is "property" or "method", object the property or the
        callable as the class gives it (a classmethod bound to its class).
    """
    out = {}
    for name in CLASSES:
        for owner in getattr(piezopreload, name).__mro__:
            if not _ours(owner):
                continue
            fields = {f.name for f in dataclasses.fields(owner)} if dataclasses.is_dataclass(owner) else set()
            for mname, raw in vars(owner).items():
                key = f"{owner.__module__}.{owner.__qualname__}.{mname}"
                if mname.startswith("_") or key in out or mname in fields:  # a field's default is no method
                    continue
                if isinstance(raw, property | cached_property):
                    out[key] = ("property", raw)
                elif isinstance(raw, classmethod | staticmethod) or inspect.isfunction(raw):
                    out[key] = ("method", getattr(owner, mname))
    return out


MEMBERS = _members()
# the test's id: the class and the member
_IDS = {k: ".".join(k.split(".")[-2:]) for k in MEMBERS}


def _documented(section):
    """The names a Parameters section documents (``a, b : float`` documents both; ``*args`` is ``args``)."""
    return {name.strip().lstrip("*") for p in section for name in p.name.split(",") if name.strip()}


def _signature(obj):
    try:
        sig = inspect.signature(obj)
    except ValueError:  # an exception type: it takes its message, as every exception does
        return [], inspect.Signature.empty
    params = [p for n, p in sig.parameters.items() if n not in ("self", "cls") and not n.startswith("_")]
    return params, sig.return_annotation


def test_the_front_door_has_names_to_check():
    assert len(NAMES) >= 50 and "load_study" in NAMES and "GainSet" in NAMES, NAMES


def test_the_methods_are_found_once_where_defined():
    """Methods, classmethods, staticmethods and properties of the exported classes, each once."""
    ids = set(_IDS.values())
    assert len(MEMBERS) >= 200, len(MEMBERS)
    # a method of a base class of ours is checked where it is defined, not in each subclass
    assert "Record.from_dict" in ids and "GainSet.from_dict" not in ids, sorted(ids)
    assert "Artifact.load" in ids  # a classmethod
    assert any(kind == "property" for kind, _ in MEMBERS.values())
    # the standard library's are not ours (an exception's with_traceback, object's __init_subclass__)
    assert not any(i.endswith(".with_traceback") for i in ids)


def _problems(name, obj):
    """What the docstring of ``obj`` lacks: a Parameters section naming each parameter, a Returns section."""
    doc = NumpyDocString(inspect.getdoc(obj) or "")
    params, returns = _signature(obj)
    out = []
    if params:
        documented = _documented(doc["Parameters"])
        if not doc["Parameters"]:
            out.append(f"{name}: no Parameters section (it takes {', '.join(p.name for p in params)})")
        missing = [p.name for p in params if p.name not in documented]
        if doc["Parameters"] and missing:
            out.append(f"{name}: parameters not in its Parameters section: {missing}")
        extra = sorted(documented - {p.name for p in params})
        if extra and not any(p.kind is p.VAR_KEYWORD for p in params):
            out.append(f"{name}: its Parameters section names what it does not take: {extra}")
    if not inspect.isclass(obj) and returns not in (None, "None", inspect.Signature.empty) \
            and not (doc["Returns"] or doc["Yields"]):
        out.append(f"{name}: returns {returns} but has no Returns section")
    return out


@pytest.mark.parametrize("name", NAMES)
def test_the_docstring_of(name):
    problems = _problems(name, getattr(piezopreload, name))
    assert not problems, "; ".join(problems)


@pytest.mark.parametrize("key", list(MEMBERS), ids=list(_IDS.values()))
def test_the_docstring_of_the_member(key):
    kind, obj = MEMBERS[key]
    name = _IDS[key]
    if kind == "property":
        assert (inspect.getdoc(obj) or "").strip(), f"{name}: a property without a docstring"
        return
    problems = _problems(name, obj)
    assert not problems, "; ".join(problems)


def test_a_name_without_sections_fails_the_check():
    """The check itself can fail: a function documented in a sentence, or naming a parameter it does not take."""

    def undocumented(path: str, strict: bool = True) -> int:
        """Count something in a file."""
        return 0

    def misnamed(path: str) -> int:
        """Count something in a file.

        Parameters
        ----------
        file : str
            The file.

        Returns
        -------
        int
            The count.
        """
        return 0

    assert len(_problems("undocumented", undocumented)) == 2
    assert [p.split(":")[1].strip()[:10] for p in _problems("misnamed", misnamed)] == ["parameters", "its Parame"]


# --------------------------------------------------------------------------------------
# a record's section against its declaration
# --------------------------------------------------------------------------------------
def _type_words(hint):
    """The words a numpydoc type must show for ``hint``, a resolved annotation.

    Parameters
    ----------
    hint : object
        The annotation as :func:`typing.get_type_hints` resolves it (``float | None``, ``tuple[Front, ...]``).

    Returns
    -------
    set of str
        The type names the documented type must name: ``{"float", "None"}``, ``{"tuple", "Front"}``; an array's
        is ``ndarray``, a dict's ``dict`` (its items are the field's doc's to say).
    """
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        words = set().union(*(_type_words(a) for a in args if a is not type(None)))
        return words | ({"None"} if type(None) in args else set())
    if hint is np.ndarray or origin is np.ndarray:
        return {"ndarray"}
    if origin is dict or hint is dict:
        return {"dict"}
    if origin in (tuple, list):
        inner = set().union(*(_type_words(a) for a in args if a is not Ellipsis)) if args else set()
        fixed = origin is tuple and Ellipsis not in args and len(args) > 1
        return inner if fixed else {origin.__name__} | inner  # a pair reads "(float, float)"
    if origin is typing.Literal:
        return {repr(a) for a in args}
    if isinstance(hint, type):
        return {hint.__name__}
    return {str(hint)}


def _shown_words(documented, cls):
    """The type names a documented type shows, a union alias of the record's module (``HysteresisModel``)
    standing for the names it unites."""
    names = vars(sys.modules[cls.__module__])
    shown = set(re.findall(r"[\w.]+", documented))
    for word in list(shown):
        alias = names.get(word)
        if typing.get_origin(alias) in (typing.Union, types.UnionType):
            shown |= _type_words(alias)
    return shown


def _field_problems(cls, f, p, hint):
    """Where the section's entry ``p`` of field ``f`` (None: there is none) differs from its declaration."""
    name = cls.__name__
    e = f.metadata.get(ENTRY)
    if e is None:
        return [f"{name}.{f.name}: declared without entry(...), so without a doc"]
    out = [] if e.doc.strip() else [f"{name}.{f.name}: its entry(...) has no doc"]
    if p is None:
        return out + [f"{name}.{f.name}: not in the Parameters section"]
    text = " ".join(" ".join(p.desc).split())
    if " ".join(e.doc.split()) not in text:
        out.append(f"{name}.{f.name}: the section says {text!r}, its declaration {e.doc!r}")
    if e.unit and f"Unit: {e.unit}." not in text:
        out.append(f"{name}.{f.name}: its unit {e.unit!r} is not in the section")
    defaulted = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    if defaulted != p.type.endswith(", optional"):
        out.append(f"{name}.{f.name}: has {'a' if defaulted else 'no'} default, the section says {p.type!r}")
    if e.choices:
        missing = [c for c in e.choices if f"'{c}'" not in p.type]
    else:
        shown = _shown_words(p.type, cls)
        missing = sorted(w for w in _type_words(hint) if w not in shown)
    if missing:
        out.append(f"{name}.{f.name}: declared {hint}, the section says {p.type!r} (no {missing})")
    return out


def _record_problems(cls):
    """Where the ``Parameters`` section of record ``cls`` differs from its fields' declarations.

    Parameters
    ----------
    cls : type
        A record made with :func:`~piezopreload.core.records.record`.

    Returns
    -------
    list of str
        One line per field that is missing from the section, has no doc, or whose section entry does not
        show its declared doc, unit, default or type.
    """
    name = cls.__name__
    doc = NumpyDocString(inspect.getdoc(cls) or "")
    section = {n.strip(): p for p in doc["Parameters"] for n in p.name.split(",") if n.strip()}
    hints = typing.get_type_hints(cls)
    declared = [f for f in dataclasses.fields(cls) if f.init]
    out = []
    for f in declared:
        out += _field_problems(cls, f, section.get(f.name), hints[f.name])
    extra = sorted(set(section) - {f.name for f in declared})
    if extra:
        out.append(f"{name}: the section names what is no field: {extra}")
    return out


def test_records_are_found():
    assert len(RECORDS) >= 20 and "GainSet" in RECORDS and "FitError" in RECORDS, RECORDS


@pytest.mark.parametrize("name", RECORDS)
def test_the_record_section_matches_its_declaration(name):
    problems = _record_problems(getattr(piezopreload, name))
    assert not problems, "; ".join(problems)


def test_a_field_added_without_its_doc_fails_the_record_check():
    """A field declared with an empty doc passes the signature check (its name is in the section) but not this."""

    @record
    class Probe(Record):
        """A probe."""

        gap_um: float = entry("The gap.", unit="um")
        load_N: float = entry("", default=0.0)

    assert _problems("Probe", Probe) == []  # the signature check cannot see it
    assert _record_problems(Probe) == ["Probe.load_N: its entry(...) has no doc"]


def test_a_section_that_differs_from_the_declaration_fails_the_record_check():
    """A section whose unit, type or default is not the declaration's is refused, field by field."""

    @record
    class Probe(Record):
        """A probe."""

        gap_um: float = entry("The gap.", unit="um")
        loads_N: tuple[float, ...] | None = entry("The loads.", default=None)

    assert _record_problems(Probe) == []
    Probe.__doc__ = Probe.__doc__.replace(" Unit: um.", "").replace("tuple of float or None, optional", "float")
    assert _record_problems(Probe) == [
        "Probe.gap_um: its unit 'um' is not in the section",
        "Probe.loads_N: has a default, the section says 'float'",
        "Probe.loads_N: declared tuple[float, ...] | None, the section says 'float' (no ['None', 'tuple'])",
    ]
