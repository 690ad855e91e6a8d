"""Fixtures shared across test files: the paper's study and its identified feedforward, and the small whole-system
study run once end to end (a minute of the suite's time, read by the system's tests and by those that run an edited
copy of it in the same folder)."""

from pathlib import Path

import pytest

from piezopreload.cli import main
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward


@pytest.fixture(scope="session")
def study():
    return load_study(paper_study())


@pytest.fixture(scope="session")
def feedforward(study):
    return identify_feedforward(study.plant, study.feedforward, check_range_N=None).model



@pytest.fixture(scope="session")
def small_axis_run(tmp_path_factory):
    """The output folder of ``piezopreload run tests/data/small_axis.toml``: every stage, run once for the session.
    A test that edits it works on a copy (``shutil.copytree``)."""
    out = tmp_path_factory.mktemp("axis") / "out"
    code = main(["run", str(Path(__file__).parent / "data" / "small_axis.toml"), "--out", str(out), "--json",
                 "--quiet"])
    assert code == 0, "the small whole-system study failed"
    return out
