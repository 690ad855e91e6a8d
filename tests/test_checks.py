"""The validation tables of the parameter dataclasses (core.checks): the first failing row is named, with its value."""

import doctest

import pytest

from piezopreload.core import checks
from piezopreload.core.checks import check_fields
from piezopreload.core.errors import InputError


class _Box:
    width_mm = 2.0
    depth_mm = -1.0
    height_mm = float("nan")


_RULES = (
    ("width_mm", lambda x: x > 0, "must be > 0"),
    ("depth_mm", lambda x: x > 0, "must be > 0"),
    ("height_mm", lambda x: x == x, "must be a number"),
)


def test_the_first_failing_row_is_named_with_its_value_and_requirement():
    with pytest.raises(ValueError) as info:
        check_fields(_Box(), "Box", _RULES)
    assert str(info.value) == "Box.depth_mm must be > 0, got -1.0."


def test_rows_that_pass_raise_nothing_and_the_error_type_is_the_callers():
    check_fields(_Box(), "Box", _RULES[:1])
    with pytest.raises(InputError, match=r"^Box\.height_mm must be a number, got nan\.$"):
        check_fields(_Box(), "Box", _RULES[2:], InputError)


def test_the_module_example_runs():
    failed, tried = doctest.testmod(checks)
    assert tried > 0 and failed == 0
