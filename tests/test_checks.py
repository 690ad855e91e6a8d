"""One schema dialect: a domain type declares each field once (``records.entry``), checked when it is made, and a
study's table reads straight into it, every message naming the key, the value and what was expected."""

import doctest

import pytest

import piezopreload as pp
from piezopreload.core import config, records
from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, TableOf, checked, entry, read_table
from piezopreload.models.actuator import Plant
from piezopreload.models.ballscrew import BallScrew
from piezopreload.spec import paper_study
from piezopreload.tuning.pid import TuningSpec


@checked
class _Box(Checked):
    """A box."""

    width_mm: float = entry("Its width.", unit="mm", gt=0, default=2.0)
    depth_mm: float = entry("Its depth.", unit="mm", gt=0, default=1.0)
    count: int = entry("How many.", ge=1, le=10, default=1)
    sizes_mm: tuple[float, ...] = entry("Its sizes.", unit="mm", gt=0, size=(1, records.MANY), default=(1.0,))

    def check(self) -> None:
        if not self.depth_mm <= self.width_mm:
            raise Invalid("depth_mm", f"must be at most width_mm ({self.width_mm:g} mm), got {self.depth_mm:g}", "_Box")


def test_the_first_field_that_fails_is_named_with_its_value_and_what_it_must_be():
    with pytest.raises(Invalid) as info:
        _Box(width_mm=2.0, depth_mm=-1.0, count=0)
    assert str(info.value) == "'_Box.depth_mm' must be a number > 0, got -1.0"
    assert isinstance(info.value, InputError) and isinstance(info.value, ValueError)
    with pytest.raises(Invalid, match=r"^'_Box.count' must be an integer >= 1 and <= 10, got 0$"):
        _Box(count=0)
    with pytest.raises(Invalid, match=r"^'_Box.sizes_mm' must be a list of 1 or more numbers > 0, got \[\]$"):
        _Box(sizes_mm=())
    with pytest.raises(Invalid, match=r"^'_Box.depth_mm' must be at most width_mm \(2 mm\), got 3$"):
        _Box(depth_mm=3.0)
    assert "width_mm : float, optional\n        Its width. Unit: mm." in (_Box.__doc__ or "")


def test_a_table_reads_into_the_type_with_the_key_s_path_and_the_same_rules():
    def fail(path, message):
        return ValueError(f"box.toml:7: '{path}' {message}")

    box = read_table(_Box, {"width_mm": 3, "sizes_mm": [1, 2]}, fail, "box")
    assert box == _Box(width_mm=3.0, sizes_mm=(1.0, 2.0)) and isinstance(box.width_mm, float)
    for data, message in (({"width_mm": -1}, "'box.width_mm' must be a number > 0, got -1"),
                          ({"count": 2.0}, "'box.count' must be an integer >= 1 and <= 10, got 2.0"),
                          ({"count": True}, "'box.count' must be an integer >= 1 and <= 10, got bool True"),
                          ({"depth_mm": 5.0}, "'box.depth_mm' must be at most width_mm (2 mm), got 5"),
                          ({"widht_mm": 1.0}, "'box.widht_mm' is an unknown key; [box] has: width_mm, depth_mm")):
        with pytest.raises(ValueError) as info:
            read_table(_Box, data, fail, "box")
        assert str(info.value).startswith(f"box.toml:7: {message}"), str(info.value)
    assert TableOf(_Box, "[box]: a box.").values(box) == {"width_mm": 3.0, "depth_mm": 1.0, "count": 1,
                                                           "sizes_mm": [1.0, 2.0]}


def test_the_domain_types_state_their_rules_once_in_one_format():
    # the case: TuningSpec.ms_max was checked twice, once without the value
    with pytest.raises(Invalid, match=r"^'TuningSpec.ms_max' must be a number > 1, got 0.9$"):
        TuningSpec(ms_max=0.9)
    with pytest.raises(Invalid, match=r"^'Plant.noise_N' must be a number >= 0, got -1.0$"):
        Plant(noise_N=-1.0)
    with pytest.raises(Invalid, match=r"^'Plant.bw_beta_per_V' must be above \|bw_gamma_per_V\| \(0.05\)"):
        Plant(bw_gamma_per_V=0.05)
    with pytest.raises(InputError, match=r"^'BallScrew.contact_angle_deg' must be a number >= 20 and <= 70, got 80"):
        BallScrew(32.0, 10.0, 6.35, 3.0, contact_angle_deg=80.0)
    # a batch of plants is checked element by element
    batch = Plant().vary(4, {"noise_N": 0.2}, seed=1)
    assert batch.batch_shape == (4,)


def test_a_study_s_tables_are_the_domain_types(tmp_path):
    study = pp.load_study("paper2021", progress=lambda _m: None)
    assert type(study.rig) is Plant and type(study.tuning) is TuningSpec
    assert type(study.validation).__name__ == "Criteria" and study.validation.band_N == study.band_N
    assert study.tuning.u_max_V == study.gains.u_max_V and study.validation.seed == study.seed
    path = tmp_path / "study.toml"
    text = paper_study().read_text()
    assert "\nms_max = 1.6 " in text
    changed = text.replace("\nms_max = 1.6 ", "\nms_max = 0.9 ", 1)
    path.write_text(changed)
    line = next(i for i, row in enumerate(changed.splitlines(), 1) if row.startswith("ms_max = 0.9"))
    with pytest.raises(InputError, match=rf"^{path}:{line}: 'tuning.ms_max' must be a number > 1, got 0.9$"):
        pp.load_study(path, progress=lambda _m: None)


def test_the_module_examples_run():
    for module in (config, records):
        failed, tried = doctest.testmod(module)
        assert tried > 0 and failed == 0, module.__name__
