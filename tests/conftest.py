"""Fixtures shared by the rig's tests: the paper's study and its identified feedforward."""

import pytest

from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward


@pytest.fixture(scope="session")
def study():
    return load_study(paper_study())


@pytest.fixture(scope="session")
def feedforward(study):
    return identify_feedforward(study.plant, study.feedforward, check_range_N=None).model

