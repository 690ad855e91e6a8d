"""Helpers for the rig's tests."""

from piezopreload.models.gainset import GainSet


def write_gain_set(path, study, feedforward, gains=None, status="validated", plant=None):
    """A gain set as 'tune' writes it (the paper's gains unless given), on the study's plant unless given."""
    GainSet(gains=gains or study.gains, status=status, feedforward=feedforward, plant=plant or study.rig,
            preset=study.name, references={k: study.references[k] for k in ("step", "trajectory")},
            criteria={"band_N": study.band_N}).save(path)
    return path
