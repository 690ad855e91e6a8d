"""Helpers for the rig's tests."""

from piezopreload.core.artifacts import write_artifact
from piezopreload.pipeline import gains_to_dict
from piezopreload.tuning_pipeline import _reference_dict


def write_gain_set(path, study, feedforward, gains=None, status="validated", plant=None):
    """A gain set as 'tune' writes it (the paper's gains unless given), on the study's plant unless given."""
    write_artifact(path, "gain-set", {
        "status": status, "gains": gains_to_dict(gains or study.gains),
        "feedforward": {"model": feedforward.to_dict()}, "plant": {"preset": study.name, "rig": (plant or study.rig).to_dict()},
        "criteria": {"band_N": study.band_N},
        "references": {k: _reference_dict(study.references[k]) for k in ("step", "trajectory")}, "inputs": {}})
    return path
