"""Fixtures shared by the rig's tests: the paper's study and its identified feedforward."""

import pytest

from piezopreload.models.actuator import Rig
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.calibrate import identify_feedforward


@pytest.fixture(scope="session")
def study():
    return load_study(paper_study())


@pytest.fixture(scope="session")
def feedforward(study):
    model, _ = identify_feedforward(Rig(study.plant), study.excitation)
    return model

