"""Helpers for the rig's tests."""

import signal

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.validation import Criteria
from piezopreload.rig.backends import Fault

#: one injected fault per interlock and the cause it must trip (both loops are tested on these)
INTERLOCK_FAULTS = [
    (Fault("nan", 1.0), "sensor_nan"),
    (Fault("stale", 1.0), "sensor_stale"),
    (Fault("offset", 1.0, 200.0), "force_high"),
    (Fault("offset", 1.0, -50.0), "force_low"),
    (Fault("reading", 1.0, 999.99), "sensor_range"),
    (Fault("raise", 1.0), "exception"),
    (Fault("signal", 1.0, float(signal.SIGTERM)), "signal"),
]


def write_gain_set(path, study, feedforward, gains=None, status="validated", plant=None):
    """A gain set as 'tune' writes it (the paper's gains unless given), on the study's plant unless given."""
    GainSet(gains=gains or study.gains, status=status, feedforward=feedforward, plant=plant or study.plant,
            preset=study.name, references={k: study.references[k] for k in ("step", "trajectory")},
            criteria=Criteria(band_N=study.band_N)).save(path)
    return path
