"""Every example on docs/autotune.md runs as written: its Python blocks in order in one session, its command lines
through the command line's entry point, each exiting 0 or with the exit code (and the quoted words) its comment
names;
what the page's comments promise of the results holds."""

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from piezopreload.cli import main

DOC = Path(__file__).resolve().parent.parent / "docs" / "autotune.md"
_BLOCK = re.compile(r"```(python|console)\n(.*?)```", re.S)
_EXPECT = re.compile(r"#\s*exit (\d+)(.*)$")


def _examples() -> list[tuple[str, str]]:
    return [(kind, body) for kind, body in _BLOCK.findall(DOC.read_text(encoding="utf-8"))]


def _files(folder: Path) -> None:
    """The files the page's examples read: a step of 40 -> 42 V through 30 N/V, 1.6 ms, 1.5 ms dead time at 0.1 ms
    (the page's FittedPlant), and the measured response of e^{-s}/(s + 1) from 0.01 to 100 rad/s."""
    t = np.arange(0.0, 0.03, 1e-4)
    tau = np.maximum(t - 0.001 - 0.0015, 0.0)
    u = np.where(t >= 0.001, 42.0, 40.0)
    y = 1520.0 + 30.0 * 2.0 * (1.0 - np.exp(-tau / 0.0016)) + 0.01 * np.random.default_rng(2).standard_normal(t.size)
    np.savetxt(folder / "step.csv", np.column_stack([t, u, y]), delimiter=",", header="time_s,input_V,force_N",
               comments="")
    w = np.logspace(-2, 2, 400)
    g = np.exp(-1j * w) / (1j * w + 1)
    np.savetxt(folder / "loop.csv", np.column_stack([w, np.abs(g), np.degrees(np.angle(g))]), delimiter=",",
               header="omega_rad_per_s,magnitude,phase_deg", comments="")


def _command(line: str, capsys: pytest.CaptureFixture) -> None:
    code, words = 0, []
    expect = _EXPECT.search(line)
    if expect:
        code, words = int(expect.group(1)), re.findall(r'"([^"]*)"', expect.group(2))
    argv = shlex.split(line.split("#")[0])
    assert argv[0] == "piezopreload", line
    got = main(argv[1:])
    err = capsys.readouterr().err
    assert got == code, f"{line}: exit {got}, expected {code}; {err}"
    if code:
        assert err.startswith("error: ") and err.count("\n") == 1, f"{line}: {err!r}"
    for w in words:
        assert w in err, f"{line}: {w!r} not in {err!r}"


def test_the_pages_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    _files(tmp_path)
    session: dict = {}
    commands = 0
    for kind, body in _examples():
        if kind == "python":
            exec(compile(body, str(DOC), "exec"), session)  # the page's own examples
            continue
        for line in body.splitlines():
            if line.strip():
                _command(line, capsys)
                commands += 1
    assert commands >= 7 and "tuned" in session and "gain_set" in session
    # what the page's comments promise
    assert session["gain_set"].status == "validated"
    assert session["gain_set"].tuning["bounds_hold_on"].startswith("the sampled loop")
    assert session["tuned"].loop == "sampled" and session["tuned"].leans_on == ()
    assert set(session["tuned"].defaults) == {"Tf_min_s"}
    assert (tmp_path / "gains.labview.txt").exists() and (tmp_path / "g.json").exists()
