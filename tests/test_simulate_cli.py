"""The study file, ``piezopreload simulate`` and ``piezopreload reproduce``."""

import json
from pathlib import Path

import numpy as np
import pytest

from piezopreload.artifacts.registry import write_artifact
from piezopreload.cli import main
from piezopreload.core.errors import InputError
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.calibrate import PAPER_RESULTS

REPO = Path(__file__).resolve().parents[1]


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_the_shipped_study_is_the_repository_one():
    assert paper_study().read_bytes() == (REPO / "studies" / "paper2021.toml").read_bytes()
    study = load_study(paper_study())
    assert study.controller.Kc == 0.3 and study.controller.Ti_s == 0.08 and study.controller.Td_s == 0.001
    assert study.controller.u_min_V == 0.0 and study.controller.u_max_V == 110.0
    assert study.rig.bolt_preload_N == 25.0
    assert study.references["step"].levels_N.tolist() == [25.0, 60.0]
    assert study.references["trajectory"].levels_N.tolist() == [25.0, 60.0, 80.0, 100.0, 80.0, 60.0]
    assert study.feedforward.n_operators == 40 and study.feedforward.v_max_V == 100.0


def test_minutes_are_converted_at_the_edge(tmp_path):
    text = paper_study().read_text().replace('units = "seconds"', 'units = "minutes"')
    path = tmp_path / "s.toml"
    path.write_text(text)
    study = load_study(path)
    assert study.controller.Ti_s == pytest.approx(4.8) and study.controller.Td_s == pytest.approx(0.06)


@pytest.mark.parametrize(
    "edit,message",
    [
        (("n_stacks = 3", "n_stacks = 3\nstiffnes = 2.0"), r":\d+: 'rig.stiffnes' is an unknown key"),
        (("Kc = 0.3", 'Kc = "high"'), r":\d+: 'controller.Kc' must be a number"),
        (('units = "seconds"', 'units = "hours"'), r":\d+: 'controller.units' must be one of seconds, minutes"),
        (("noise_N = ", "noise_N = -"), r":\d+: 'rig.noise_N' must be a number >= 0"),
        (("band_N = 1.5", "band_N = 0.0"), r":\d+: 'simulation.band_N' must be a number > 0"),
        (("hold_s = 5.0", "hold_s = nan"), r":\d+: 'reference.trajectory.hold_s' must be a number > 0, got nan"),
        (("[controller]", "[controler]"), r":\d+: 'controler' is an unknown table"),
    ],
)
def test_bad_study_files_name_the_line_and_key(tmp_path, edit, message):
    text = paper_study().read_text()
    assert edit[0] in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(InputError, match=message):
        load_study(path)


def test_study_line_numbers_point_at_the_key(tmp_path):
    text = paper_study().read_text().replace("Kc = 0.3", 'Kc = "x"')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    line = next(i for i, s in enumerate(text.splitlines(), 1) if s.startswith("Kc ="))
    with pytest.raises(InputError, match=f"bad.toml:{line}: 'controller.Kc'"):
        load_study(path)


def test_simulate_step_json_holds_the_metrics_and_the_published_ones(capsys, tmp_path):
    out = tmp_path / "run.csv"
    code, stdout, err = run_cli(capsys, "simulate", "--study", "paper2021", "--controller", "pid", "--out", str(out),
                                "--json")
    assert code == 0, err
    s = json.loads(stdout)
    for key in ("rise_s", "peak_s", "settling_s", "overshoot_N"):
        assert key in s
    assert {k: s["published"][k] for k in ("rise_s", "peak_s", "settling_s")} == PAPER_RESULTS["pid"]
    assert "overshoot_N" not in s["published"]  # not published
    assert 0 < s["rise_s"] <= s["settling_s"]
    data = np.loadtxt(out, delimiter=",", comments="#", skiprows=2)
    header = [line for line in out.read_text().splitlines() if not line.startswith("#")][0].split(",")
    assert header[:4] == ["time_s", "reference_N", "force_N", "measured_N"]
    assert data.shape == (s["samples"], len(header))
    # the CSV is the run the metrics came from: same command peak
    assert data[:, header.index("command_V")].max() == pytest.approx(s["peak_command_V"], rel=1e-8)


def test_simulate_trajectory_reports_tracking(capsys):
    code, stdout, err = run_cli(capsys, "simulate", "--study", "paper2021", "--reference", "trajectory", "--json")
    assert code == 0, err
    s = json.loads(stdout)
    assert s["controller"] == "ff+pid" and s["feedforward"]["operators"] == 40
    assert 0 < s["tracking_rms_N"] < s["tracking_max_N"] <= 36.0
    assert s["published"] is None, "the paper publishes no trajectory numbers"


def test_a_study_without_published_numbers_compares_with_none(capsys, tmp_path):
    """The paper's numbers appear only where a study declares them: without [published], simulate shows none and
    reproduce is refused, naming the table."""
    text = paper_study().read_text()
    start, end = text.index("[published]"), text.index("[rig]")
    study = tmp_path / "mine.toml"
    study.write_text(text[:start] + text[end:])
    code, stdout, err = run_cli(capsys, "simulate", "--study", str(study), "--controller", "pid", "--json")
    assert code == 0, err
    assert json.loads(stdout)["published"] is None
    code, stdout, err = run_cli(capsys, "simulate", "--study", str(study), "--controller", "pid")
    table = stdout.split("simulated", 1)[1]  # the lines after the header name the file, which names this test
    assert code == 0 and "published" not in table and "paper" not in table
    code, stdout, err = run_cli(capsys, "reproduce", "--study", str(study))
    assert code == 2 and "declares no published step numbers" in err and "[published]" in err


def test_simulate_text_output_and_seed(capsys):
    code, stdout, _ = run_cli(capsys, "simulate", "--study", "paper2021", "--controller", "pid", "--seed", "3")
    assert code == 0
    assert "rise time (s)" in stdout and "1.690" in stdout and "seed 3" in stdout


def _gain_file(path, gains):
    write_artifact(path, "gain-set", {"status": "candidate", "inputs": {}, "gains": gains})
    return path


def test_a_tampered_gain_file_is_refused(capsys, tmp_path):
    g = _gain_file(tmp_path / "g.json", {"Kc_V_per_N": 0.5, "Ti_s": 0.1, "Td_s": 0.0})
    doc = json.loads(g.read_text())
    doc["gains"]["Kc_V_per_N"] = 5.0
    g.write_text(json.dumps(doc))
    code, _, err = run_cli(capsys, "simulate", "--study", "paper2021", "--controller", "pid", "--gains", str(g))
    assert code == 2 and "field 'content_sha256' does not match the content" in err and err.count("\n") == 1


def test_simulate_with_a_gain_file(capsys, tmp_path):
    g = _gain_file(tmp_path / "g.json", {"Kc_V_per_N": 0.5, "Ti_s": 0.1, "Td_s": 0.0})
    code, stdout, err = run_cli(capsys, "simulate", "--study", "paper2021", "--controller", "pid", "--gains", str(g),
                                "--json")
    assert code == 0, err
    s = json.loads(stdout)
    assert s["gains"]["Kc_V_per_N"] == 0.5 and s["gains"]["source"] == str(g)


@pytest.mark.parametrize(
    "argv_tail,needle",
    [
        (["--study", "missing.toml"], "missing.toml: no such study file"),
        (["--controller", "mpc"], "invalid choice: 'mpc'"),
        (["--seed", "-1"], "must be an integer >= 0"),
    ],
)
def test_simulate_bad_input_exits_2(capsys, argv_tail, needle):
    code, out, err = run_cli(capsys, "simulate", *argv_tail)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and needle in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "gains,needle",
    [
        ({"Kc_V_per_N": 0.5, "Td_s": 0.0}, "field 'gains.Ti_s' is missing"),
        ({"Kc_V_per_N": 0.5, "Ti_s": -1.0, "Td_s": 0.0}, "'PIDGains.Ti_s' must be a number > 0, or inf for no integral "
                                                     "action, got -1.0"),
        ({"Kc_V_per_N": float("nan"), "Ti_s": 1.0, "Td_s": 0.0}, "'gains.Kc_V_per_N' must be a finite number"),
    ],
)
def test_simulate_rejects_bad_gain_files(capsys, tmp_path, gains, needle):
    if any(isinstance(v, float) and v != v for v in gains.values()):
        # a NaN cannot be written (or hashed) by write_artifact: as a hand-edited file would hold it
        g = tmp_path / "g.json"
        g.write_text(json.dumps({"schema": "piezopreload/gain-set/1", "status": "candidate", "inputs": {},
                                 "gains": gains, "content_sha256": "0" * 64}))
    else:
        g = _gain_file(tmp_path / "g.json", gains)
    code, _, err = run_cli(capsys, "simulate", "--study", "paper2021", "--gains", str(g))
    assert code == 2 and needle in err, err


def test_reproduce_prints_the_six_numbers(capsys):
    code, stdout, err = run_cli(capsys, "reproduce", "--study", "paper2021", "--json")
    assert code == 0, err
    s = json.loads(stdout)
    rows = {(r["controller"], r["metric"]): r for r in s["rows"]}
    assert len(rows) == 6
    for c, metrics in PAPER_RESULTS.items():
        for k, v in metrics.items():
            assert rows[(c, k)]["paper"] == v
            assert rows[(c, k)]["simulated"] > 0
    # the feedforward makes the step faster, as in the paper
    assert rows[("ff+pid", "rise_s")]["simulated"] < 0.2 * rows[("pid", "rise_s")]["simulated"]
