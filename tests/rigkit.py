"""Helpers for the rig's tests: gain sets, the interlocks' fire drills, the event logs the two loops must share."""

import signal

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.validation import Criteria
from piezopreload.rig.backends import Fault

#: one injected fault per interlock and the cause it must trip (both loops are tested on these)
INTERLOCK_FAULTS = [
    (Fault("nan", 1.0), "sensor_nan"),
    (Fault("stale", 1.0), "sensor_stale"),
    (Fault("offset", 1.0, 200.0), "force_high"),
    (Fault("offset", 1.0, -50.0), "force_low"),
    (Fault("reading", 1.0, 999.99), "sensor_range"),
    (Fault("delay", 1.0, 0.25, 0.001), "stall"),  # with a stall limit of STALL_LIMIT_S
    (Fault("raise", 1.0), "exception"),
    (Fault("signal", 1.0, float(signal.SIGTERM)), "signal"),
]

#: the stall limit the fault scripts run with (shorter than the plant's, as a study or --stall-limit-s may ask)
STALL_LIMIT_S = 0.1

#: one run's fire drill: stalls shorter than the limit (counted and logged, not tripped), then one longer (trips)
STALL_SCRIPT = [Fault("delay", 0.3, 0.004, 0.001), Fault("delay", 0.6, 0.02, 0.003), Fault("delay", 1.0, 0.2, 0.001)]
#: the stalls STALL_SCRIPT makes on the virtual clock: (t_s, the output held s) of each, the last one tripping
STALL_SCRIPT_STALLS = [(0.3, 0.005), (0.6, 0.021), (0.601, 0.020), (0.602, 0.020), (1.0, 0.201)]

#: the keys of an event that say which loop ran (they differ between the loops by design)
LOOP_KEYS = {"utc", "loop", "loop_reason", "sched_fifo", "memory_locked"}


def events(sidecar) -> list[dict]:
    """A run's events without their wall-clock times and the loop's own description: what both loops must share."""
    return [{k: v for k, v in e.items() if k not in LOOP_KEYS} for e in RigRunRecord.load(sidecar).events]


def write_gain_set(path, study, feedforward, gains=None, status="validated", plant=None, rig_interlocks=None):
    """A gain set as 'tune' writes it (the paper's gains unless given), on the study's plant unless given."""
    GainSet(gains=gains or study.controller, status=status, feedforward=feedforward, plant=plant or study.plant,
            preset=study.name, references={k: study.references[k] for k in ("step", "trajectory")},
            criteria=Criteria(band_N=study.band_N), rig_interlocks=rig_interlocks).save(path)
    return path
