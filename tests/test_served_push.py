"""What a served rig accepts when a gain set is pushed to it (rig.session.check_pushed), without a server.

The served rig runs the paper's gain set on its plant, armed with the limits its study derives (force_max_N 1.25 x
the force the stacks reach, the executor's margin and ramp, the stall limit the plant tolerates). A pushed gain set
must be for the same plant (its hash), validated, at the loop's period, and its limits must fit the armed ones: the
rig trips no later than the pushed set's study asks (within rig.limits.FIT_TOLERANCE), ramps down the same way and
commands the same range. Every refusal is a sentence (never a Python repr) that says what to do.
tests/test_opcua.py pushes through the server and checks the switch in the run log.
"""

import dataclasses

import pytest
from rigkit import write_gain_set

from piezopreload.artifacts.gainset import GainSet, RigInterlocks
from piezopreload.models.controller import GainSchedule, PIDGains
from piezopreload.rig.limits import FIT_TOLERANCE, run_limits
from piezopreload.rig.session import ServedRig, check_pushed

RETUNED = PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.001, Tf_s=0.01, b=0.0, u_min_V=0.0, u_max_V=110.0)


@pytest.fixture(scope="module")
def served(study, feedforward, tmp_path_factory):
    """The served rig: the paper's gain set on its plant, armed as 'rig serve' arms it (no overrides)."""
    path = write_gain_set(tmp_path_factory.mktemp("served") / "paper.json", study, feedforward)
    return _served(GainSet.load(path))


def _served(gs, overrides=None):
    controller, ref = gs.controller(), gs.references["step"]
    limits = run_limits(gs, controller, ref, "step", overrides=overrides)
    return ServedRig(gs.plant_sha256, gs.preset, limits, dict(overrides or {}), ref, "step", 0, None, controller.dt_s,
                     controller.model, compiled=True, native=True)


def _push(tmp_path, study, feedforward, served, **kwargs):
    path = write_gain_set(tmp_path / "pushed.json", study, feedforward, **kwargs)
    return check_pushed(path.read_text(), served)


def _refused(tmp_path, study, feedforward, served, match, **kwargs):
    with pytest.raises(ValueError, match=match) as info:
        _push(tmp_path, study, feedforward, served, **kwargs)
    text = str(info.value)
    assert "ControllerModel(" not in text and "InverseStep(" not in text and "{" not in text, "a repr in " + text
    return text


def test_a_retuned_and_a_redesigned_gain_set_of_the_rigs_plant_are_accepted(tmp_path, study, feedforward, served):
    controller, info = _push(tmp_path, study, feedforward, served, gains=RETUNED)
    assert controller.gains.Kc == 0.5 and info["controller"] == "PID with a classical feedforward of 40 operators"
    assert info["interlocks_kept"] == []
    schedule = GainSchedule(levels_N=(40.0, 60.0, 100.0), Kc=(0.4, 0.6, 0.5), Ti_s=(0.06, 0.05, 0.05),
                            Td_s=(0.001, 0.001, 0.001))
    controller, info = _push(tmp_path, study, feedforward, served,
                             gains=dataclasses.replace(RETUNED, schedule=schedule))
    assert controller.model.schedule_size == 3 and "a gain schedule of 3 entries" in info["controller"]
    # no feedforward where the served one has one: another structure still, accepted
    controller, info = _push(tmp_path, study, None, served, gains=RETUNED)
    assert controller.feedforward is None and info["controller"] == "PID"


def test_looser_limits_are_kept_as_the_rig_was_armed_and_said_so(tmp_path, study, feedforward, served):
    armed = served.limits.safety.force_max_N
    _, info = _push(tmp_path, study, feedforward, served, gains=RETUNED,
                    rig_interlocks=RigInterlocks(armed + 40.0, 10.0, 0.5, None, {"force_max_N": "other.toml"}))
    source = served.limits.sources.force_max_N
    assert info["interlocks_kept"] == [f"force_max_N: the rig keeps {armed:g} ({source}), stricter than the pushed "
                                       f"gain set's {armed + 40.0:g} (the gain set: other.toml)"]
    # within the tolerance: the same limit (a value written to four digits)
    _, info = _push(tmp_path, study, feedforward, served, gains=RETUNED,
                    rig_interlocks=RigInterlocks(armed * (1 - 0.5 * FIT_TOLERANCE), 10.0, 0.5))
    assert info["interlocks_kept"] == []


def test_stricter_limits_are_refused_with_what_to_do(tmp_path, study, feedforward, served):
    armed = served.limits.safety
    text = _refused(tmp_path, study, feedforward, served, r"trip the force above 130 N .* this rig trips only above",
                    gains=RETUNED, rig_interlocks=RigInterlocks(130.0, 10.0, 0.5))
    assert text.endswith("serve the rig with this gain set, or start it with --force-max-N 130")
    low_N = armed.bolt_preload_N - 5
    _refused(tmp_path, study, feedforward, served, rf"trip the force below {low_N:g} N .* --force-low", gains=RETUNED,
             rig_interlocks=RigInterlocks(armed.force_max_N, 5.0, 0.5))
    _refused(tmp_path, study, feedforward, served, r"ramps the rig down over 2 s .* --ramp-s 2",
             gains=RETUNED, rig_interlocks=RigInterlocks(armed.force_max_N, 10.0, 2.0))
    _refused(tmp_path, study, feedforward, served, r"output held 20 ms without an update .* --stall-limit-s 0.02",
             gains=RETUNED, rig_interlocks=RigInterlocks(armed.force_max_N, 10.0, 0.5, 0.02))
    # served with the command line's --force-max-N 130, the same gain set fits: an override holds for any push
    low = _served(served_gain_set(tmp_path, study, feedforward), {"force_max_N": 130.0})
    _, info = _push(tmp_path, study, feedforward, low, gains=RETUNED, rig_interlocks=RigInterlocks(130.0, 10.0, 0.5))
    assert info["interlocks_kept"] == []


def served_gain_set(tmp_path, study, feedforward):
    return GainSet.load(write_gain_set(tmp_path / "served.json", study, feedforward))


def test_another_plant_range_period_or_status_is_refused_in_a_sentence(tmp_path, study, feedforward, served):
    _refused(tmp_path, study, feedforward, served, r"validated on another plant \('paper2021', plant sha256 \w{12}\) "
             r"than this rig runs .* a gain set runs only on the plant it was validated on",
             gains=RETUNED, plant=dataclasses.replace(study.plant, noise_N=0.05))
    _refused(tmp_path, study, feedforward, served, r"commands 0 to 100 V .* armed for 0 to 110 V .* could jump at the "
             r"switch", gains=dataclasses.replace(RETUNED, u_max_V=100.0))
    _refused(tmp_path, study, feedforward, served, r"the pushed gain set is a 'candidate', not 'validated' \(it was "
             r"never validated\): only validated gains are pushed", gains=RETUNED, status="candidate")
    slower = _served(served_gain_set(tmp_path, study, feedforward))
    slower = dataclasses.replace(slower, dt_s=2 * slower.dt_s)
    _refused(tmp_path, study, feedforward, slower, r"samples every 0.001 s, this rig's loop every 0.002 s",
             gains=RETUNED)
