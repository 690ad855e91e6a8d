"""Each public name of the front door documents what it takes and what it gives, in numpydoc's sections.

After python-control's ``control/tests/docstrings_test.py``: a function's or a class's docstring
must have a ``Parameters`` section naming every parameter of its signature (and no parameter it
does not take), and a function that returns something a ``Returns`` section. The sections are
read by numpydoc's own parser, as the documentation site reads them.
"""

import inspect

import pytest
from numpydoc.docscrape import NumpyDocString

import piezopreload

NAMES = [n for n in piezopreload.__all__ if callable(getattr(piezopreload, n))]


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
