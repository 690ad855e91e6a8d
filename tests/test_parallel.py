"""Work started beside the current one gives what running it here gives, errors included."""

import os

import pytest

from piezopreload.core.errors import InputError
from piezopreload.core.parallel import beside, spare_cpus


def _square_and_pid(x):
    return x * x, os.getpid()


def _refuse(x):
    raise InputError(f"x = {x}: expected a positive number")


@pytest.mark.parametrize("workers", ["1", "2"])
def test_the_same_result_in_a_worker_or_here(monkeypatch, workers):
    monkeypatch.setenv("PIEZOPRELOAD_WORKERS", workers)
    job = beside(_square_and_pid, 7)
    value, pid = job.result()
    assert value == 49
    assert job.in_worker is False  # collected
    assert (pid != os.getpid()) == (workers == "2" and spare_cpus() > 1), "ran where it should not have"


@pytest.mark.parametrize("workers", ["1", "2"])
def test_an_error_comes_back_with_its_type_and_message(monkeypatch, workers):
    monkeypatch.setenv("PIEZOPRELOAD_WORKERS", workers)
    job = beside(_refuse, -1)
    with pytest.raises(InputError, match="x = -1: expected a positive number"):
        job.result()


def _slow(x):
    import time

    time.sleep(1.0)
    return x


def test_a_discarded_job_does_not_hold_its_caller(monkeypatch):
    import time

    monkeypatch.setenv("PIEZOPRELOAD_WORKERS", "2")
    job = beside(_slow, 1)
    t0 = time.perf_counter()
    job.discard()
    assert time.perf_counter() - t0 < 0.5, "discard waited for the worker"
    assert job.result() is None


@pytest.mark.parametrize("bad", ["two", "0", "-3"])
def test_a_bad_worker_count_is_refused_by_name(monkeypatch, bad):
    monkeypatch.setenv("PIEZOPRELOAD_WORKERS", bad)
    with pytest.raises(InputError, match=f"PIEZOPRELOAD_WORKERS='{bad}': expected a whole number"):
        spare_cpus()
