"""One schema dialect: a domain type declares each field once (``records.entry``), checked when it is made, and a
study's table reads straight into it, every message naming the key, the value and what was expected."""

import doctest

import pytest

import piezopreload as pp
from piezopreload.core import config, records
from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, TableOf, UnitKey, checked, entry, read_table
from piezopreload.models.actuator import Plant
from piezopreload.models.ballscrew import BallScrew
from piezopreload.models.controller import PIDGains
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
    assert study.tuning.u_max_V == study.controller.u_max_V and study.validation.seed == study.seed
    path = tmp_path / "study.toml"
    text = paper_study().read_text()
    assert "\nms_max = 1.6 " in text
    changed = text.replace("\nms_max = 1.6 ", "\nms_max = 0.9 ", 1)
    path.write_text(changed)
    line = next(i for i, row in enumerate(changed.splitlines(), 1) if row.startswith("ms_max = 0.9"))
    with pytest.raises(InputError, match=rf"^{path}:{line}: 'tuning.ms_max' must be a number > 1, got 0.9$"):
        pp.load_study(path, progress=lambda _m: None)


def test_the_study_s_gains_are_pid_gains_read_in_seconds_whatever_the_file_enters(tmp_path):
    """[controller] reads straight into PIDGains (no table beside it, no twin): Ti and Td entered in LabVIEW's
    minutes are held in seconds, and the study says which unit the file entered."""
    study = pp.load_study("paper2021", progress=lambda _m: None)
    assert type(study.controller) is PIDGains and not hasattr(study, "gains")
    assert study.controller == PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001) and study.controller_units == "seconds"
    path = tmp_path / "study.toml"
    path.write_text(paper_study().read_text().replace('units = "seconds"', 'units = "minutes"'))
    minutes = pp.load_study(path, progress=lambda _m: None)
    assert type(minutes.controller) is PIDGains and minutes.controller_units == "minutes"
    assert minutes.controller == PIDGains.from_labview(0.3, 0.08, 0.001)  # 4.8 s and 0.06 s


def test_the_gains_state_their_rules_once_for_code_and_for_a_study(tmp_path):
    # the output range's rule: one predicate, from PIDGains made in code and from a study's [controller]
    with pytest.raises(Invalid, match=r"^'PIDGains.u_max_V' must be above u_min_V \(0 V\), got -30$"):
        PIDGains(Kc=0.3, Ti_s=0.08, u_max_V=-30.0)
    with pytest.raises(Invalid, match=r"^'PIDGains.Td_s' must be a number >= 0, got -0.001$"):
        PIDGains(Kc=0.3, Ti_s=0.08, Td_s=-0.001)
    text = paper_study().read_text()
    assert "\nu_max_V = 110.0" in text
    changed = text.replace("\nu_max_V = 110.0", "\nu_max_V = -30.0", 1)
    path = tmp_path / "study.toml"
    path.write_text(changed)
    line = next(i for i, row in enumerate(changed.splitlines(), 1) if row.startswith("u_max_V = -30.0"))
    with pytest.raises(InputError, match=rf"^{path}:{line}: 'controller.u_max_V' must be above u_min_V \(0 V\), "
                                         r"got -30$"):
        pp.load_study(path, progress=lambda _m: None)
    # in code, inf is no integral action; a study's Ti is finite (its gains go into JSON, which holds no infinity)
    assert PIDGains(Kc=0.3, Ti_s=float("inf")).Ti_s == float("inf")
    with pytest.raises(Invalid, match=r"^'PIDGains.Ti_s' must be a number > 0, or inf for no integral action, "
                                      r"got -1.0$"):
        PIDGains(Kc=0.3, Ti_s=-1.0)
    changed = text.replace("\nTi = 0.08\n", "\nTi = inf\n", 1)
    path.write_text(changed)
    line = next(i for i, row in enumerate(changed.splitlines(), 1) if row.startswith("Ti = inf"))
    with pytest.raises(InputError, match=rf"^{path}:{line}: 'controller.Ti' must be a number > 0, got inf$"):
        pp.load_study(path, progress=lambda _m: None)


@checked
class _Timer(Checked):
    """A timer whose times a table may enter in minutes."""

    delay_s: float = entry("the delay", name="delay", ge=0)
    period_s: float = entry("the period", name="period", gt=0, default=1.0, required=True)
    count: int = entry("how many", default=1, ge=1)


def test_a_unit_key_converts_the_numbers_it_names_as_the_table_is_read():
    units = UnitKey("units", "the unit of delay and period", (("seconds", 1.0), ("minutes", 60.0)),
                    ("delay_s", "period_s"))
    table = TableOf(_Timer, "[timer]: a timer.", unit=units)

    def fail(path, message):
        return InputError(f"'{path}' {message}")

    assert table.parse({"delay": 2, "period": 0.5}, fail, "timer") == _Timer(2.0, 0.5)
    assert table.parse({"delay": 2, "period": 0.5, "count": 3, "units": "minutes"}, fail, "timer") == \
        _Timer(120.0, 30.0, 3)  # count is no time: as entered
    with pytest.raises(InputError, match=r"^'timer.units' must be one of seconds, minutes, got 'hours'$"):
        table.parse({"delay": 2, "period": 1, "units": "hours"}, fail, "timer")
    with pytest.raises(InputError, match=r"^'timer.delay' must be a number >= 0, got -1$"):  # the value as entered
        table.parse({"delay": -1, "period": 1, "units": "minutes"}, fail, "timer")
    with pytest.raises(InputError, match=r"^'timer' needs 'period' \(a number > 0\)$"):  # a file must give it
        table.parse({"delay": 1}, fail, "timer")
    with pytest.raises(InputError, match=r"^'timer.unit' is an unknown key; \[timer\] has: delay, period, count, "
                                         r"units$"):
        table.parse({"delay": 1, "period": 1, "unit": "minutes"}, fail, "timer")
    assert table.rows()[-1] == ("units", "one of seconds, minutes", '`"seconds"`', "", "the unit of delay and period")
    assert table.rows()[1][2] == "required"  # a default for code, not for files


def test_the_module_examples_run():
    for module in (config, records):
        failed, tried = doctest.testmod(module)
        assert tried > 0 and failed == 0, module.__name__
