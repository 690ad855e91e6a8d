"""A run's pool gives what running the work here gives, errors included; worker counts are arguments, not the
environment, and nothing in the package writes the environment."""

import ast
import concurrent.futures as cf
import os
from pathlib import Path

import pytest

from piezopreload.core.errors import InputError
from piezopreload.core.parallel import Pool, default_workers

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ("core", "models", "artifacts", "design", "tuning", "rig", "reports", "piezopreload")


def _square_and_pid(x):
    return x * x, os.getpid()


def _refuse(x):
    raise InputError(f"x = {x}: expected a positive number")


@pytest.mark.parametrize("workers", [1, 2])
def test_the_same_result_in_a_worker_or_here(workers):
    with Pool(workers) as pool:
        job = pool.beside(_square_and_pid, 7)
        value, pid = job.result()
        more = [f.result()[0] for f in [pool.submit(_square_and_pid, x) for x in range(5)]]
    assert value == 49 and more == [0, 1, 4, 9, 16]
    assert (pid != os.getpid()) == pool.parallel, "ran where it should not have"
    assert pool.description == ("2 local processes" if pool.parallel else "inline")


@pytest.mark.parametrize("workers", [1, 2])
def test_an_error_comes_back_with_its_type_and_message(workers):
    with Pool(workers) as pool:
        job = pool.beside(_refuse, -1)
        with pytest.raises(InputError, match="x = -1: expected a positive number"):
            job.result()


def test_the_workers_are_forked_once_per_pool_not_once_per_job(monkeypatch):
    """One process pool per run: every job of the run goes to the same processes."""
    made = []
    init = cf.ProcessPoolExecutor.__init__

    def counting(self, *args, **kwargs):
        made.append(kwargs.get("max_workers"))
        init(self, *args, **kwargs)

    monkeypatch.setattr(cf.ProcessPoolExecutor, "__init__", counting)
    with Pool(2) as pool:
        pids = {pool.beside(_square_and_pid, x).result()[1] for x in range(6)}
        pids |= {f.result()[1] for f in [pool.submit(_square_and_pid, x) for x in range(6)]}
    if pool.parallel:
        assert made == [2], f"process pools made: {made}"
        assert len(pids) <= 2 and os.getpid() not in pids
    with Pool(1) as serial:
        assert serial.beside(_square_and_pid, 3).result() == (9, os.getpid())
    assert made in ([2], []), "one worker made processes"


def test_a_shut_pool_takes_no_more_work():
    pool = Pool(1)
    pool.shutdown()
    with pytest.raises(RuntimeError, match="shut down"):
        pool.submit(_square_and_pid, 1)


def _slow(x):
    import time

    time.sleep(1.0)
    return x


def test_a_discarded_job_does_not_hold_its_caller():
    import time

    with Pool(2) as pool:
        job = pool.beside(_slow, 1)
        t0 = time.perf_counter()
        job.discard()
        assert time.perf_counter() - t0 < 0.5, "discard waited for the worker"
        assert job.result() is None


@pytest.mark.parametrize("bad", ["two", "0", "-3"])
def test_a_bad_worker_count_is_refused_by_name(bad):
    with pytest.raises(InputError, match=f"PIEZOPRELOAD_WORKERS='{bad}': expected a whole number"):
        default_workers({"PIEZOPRELOAD_WORKERS": bad})
    with pytest.raises(InputError, match="workers: must be a whole number >= 1"):
        Pool(0)


def test_the_user_s_setting_is_read_not_written(monkeypatch):
    monkeypatch.setenv("PIEZOPRELOAD_WORKERS", "3")
    before = dict(os.environ)
    assert default_workers() == 3
    assert default_workers({}) == (os.cpu_count() or 1)
    assert dict(os.environ) == before


def _environ_writes(tree: ast.AST) -> list[int]:
    """Lines that write ``os.environ`` (an item assigned or deleted, a mutating method) or call ``os.putenv``."""
    def is_environ(node: ast.AST) -> bool:
        return isinstance(node, ast.Attribute) and node.attr == "environ"

    lines = []
    for node in ast.walk(tree):
        targets = (node.targets if isinstance(node, ast.Assign) else [node.target]
                   if isinstance(node, ast.AugAssign | ast.AnnAssign) else node.targets
                   if isinstance(node, ast.Delete) else [])
        if any(isinstance(t, ast.Subscript) and is_environ(t.value) for t in targets):
            lines.append(node.lineno)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            f = node.func
            if (is_environ(f.value) and f.attr in ("pop", "setdefault", "update", "clear", "popitem")) or \
                    f.attr in ("putenv", "unsetenv"):
                lines.append(node.lineno)
    return sorted(lines)


def test_the_check_finds_a_write():
    tree = ast.parse("import os\nos.environ['A'] = '1'\nos.environ.pop('A')\nx = os.environ.get('A')\n"
                     "del os.environ['B']\nos.putenv('C', '1')\n")
    assert sorted(_environ_writes(tree)) == [2, 3, 5, 6]


def test_no_module_of_the_package_writes_the_environment():
    """Worker counts travel as arguments: no floor steers another by setting a variable (issue 42, item 5)."""
    writes = {}
    for floor in FLOORS:
        for path in sorted((ROOT / floor).rglob("*.py")):
            found = _environ_writes(ast.parse(path.read_text(encoding="utf-8")))
            if found:
                writes[str(path.relative_to(ROOT))] = found
    assert not writes, f"os.environ written at {writes}"


def _numbers(doc):
    """A document without what a run's timing, its worker count or its files' hashes decide."""
    if isinstance(doc, dict):
        return {k: _numbers(v) for k, v in doc.items()
                if k not in ("created_utc", "started_utc", "finished_utc", "seconds", "workers", "key", "path",
                             "pdf_bytes") and not k.endswith("sha256")}
    if isinstance(doc, list):
        return [_numbers(v) for v in doc]
    return doc


@pytest.mark.slow
def test_a_run_makes_one_pool_and_gives_the_same_numbers_on_one_worker_or_two(tmp_path, monkeypatch):
    """The small study run end to end with ``workers=1`` (no process) and ``workers=2`` (one pool of two for the whole
    run: the bound beside the tuning, the Monte Carlo chunks and the figures share it): the same gains, tuning,
    validation and stage summaries."""
    import json

    from piezopreload.pipeline import run_study
    from piezopreload.progress import Progress

    made = []
    init = cf.ProcessPoolExecutor.__init__

    def counting(self, *args, **kwargs):
        made.append(kwargs.get("max_workers"))
        init(self, *args, **kwargs)

    monkeypatch.setattr(cf.ProcessPoolExecutor, "__init__", counting)
    docs = {}
    for workers in (1, 2):
        made.clear()
        out = tmp_path / f"w{workers}"
        run_study(ROOT / "tests" / "data" / "small_study.toml", out, workers=workers, progress=Progress(quiet=True))
        assert made == ([] if workers == 1 else [2]), f"workers={workers}: process pools made {made}"
        docs[workers] = {name: _numbers(json.loads((out / name).read_text()))
                         for name in ("gains.json", "tuning.json", "validation.json", "pipeline.json")}
    for name in docs[1]:
        assert docs[1][name] == docs[2][name], f"{name} differs between one worker and two"
    assert docs[1]["validation.json"]["metrics"] and docs[1]["tuning.json"]["gains"], "nothing compared"
