"""The study file: cases of a grid and of a seeded sample; every bad key or value refused with key, value and rule."""

from __future__ import annotations

from pathlib import Path

import pytest

from clm_core.errors import ParameterError
from clm_core.studies.spec import load_study, parse_study, simulate_argv

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "studies"


def test_grid_is_the_full_product_last_name_fastest() -> None:
    spec = parse_study({"settings": {"duration": 0.2}, "grid": {"speed": [40, 80], "soil": ["soft", "stiff"],
                                                                "seed": {"range": [1, 4]}}})
    cases = spec.cases()
    assert len(cases) == 2 * 2 * 3
    assert spec.varied == ["speed", "soil", "seed"]
    assert [c.values for c in cases[:4]] == [
        {"speed": 40.0, "soil": "soft", "seed": 1}, {"speed": 40.0, "soil": "soft", "seed": 2},
        {"speed": 40.0, "soil": "soft", "seed": 3}, {"speed": 40.0, "soil": "stiff", "seed": 1},
    ]
    assert isinstance(cases[0].values["speed"], float)  # a real-valued setting: 40 -> 40.0
    assert all(c.settings["duration"] == 0.2 for c in cases)
    assert len({c.key for c in cases}) == len(cases)
    assert [c.index for c in cases] == list(range(len(cases)))


def test_grid_forms() -> None:
    spec = parse_study({"grid": {"speed": {"linspace": [20, 150, 14]}, "soil.kf": {"geomspace": [1e6, 1e8, 3]},
                                 "seed": {"range": [0, 10, 5]}}})
    assert spec.grid["speed"][0] == 20.0 and spec.grid["speed"][-1] == 150.0 and len(spec.grid["speed"]) == 14
    assert spec.grid["soil.kf"] == pytest.approx([1e6, 1e7, 1e8])
    assert spec.grid["seed"] == [0, 5]


def test_sample_is_seeded_and_each_parameter_has_its_own_stream() -> None:
    base = {"n": 20, "seed": 7, "vary": {"seed": {"integers": [0, 1000]}, "speed": {"uniform": [40, 90]}}}
    a = parse_study({"sample": base}).cases()
    b = parse_study({"sample": base}).cases()
    assert [c.values for c in a] == [c.values for c in b]
    assert all(0 <= c.values["seed"] <= 1000 and 40 <= c.values["speed"] <= 90 for c in a)
    # adding a parameter leaves the other draws as they were
    more = {**base, "vary": {**base["vary"], "soil": {"choice": ["soft", "medium", "stiff"]}}}
    c = parse_study({"sample": more}).cases()
    assert [x.values["seed"] for x in c] == [x.values["seed"] for x in a]
    assert {x.values["soil"] for x in c} <= {"soft", "medium", "stiff"}
    # another seed, other draws
    other = parse_study({"sample": {**base, "seed": 8}}).cases()
    assert [x.values["seed"] for x in other] != [x.values["seed"] for x in a]


def test_grid_crossed_with_sample() -> None:
    spec = parse_study({"grid": {"speed": [50, 70, 90]}, "sample": {"n": 4, "seed": 1,
                                                                   "vary": {"seed": {"integers": [0, 99]}}}})
    cases = spec.cases()
    assert len(cases) == 12
    seeds = [c.values["seed"] for c in cases]
    assert seeds[:4] == seeds[4:8] == seeds[8:]  # the same draws at every grid point


@pytest.mark.parametrize(
    ("data", "words"),
    [
        ({"settings": {"sped": 60}}, ["settings.sped", "unknown setting 'sped'", "speed"]),
        ({"grid": {"speed": [60, 200]}}, ["grid.speed[1]", "200", "must be 0 to 150 m/s"]),
        ({"settings": {"dt": "small"}}, ["dt", "'small'", "must be a real number"]),
        ({"settings": {"seed": 1.5}}, ["seed", "1.5", "must be an integer"]),
        ({"grid": {"soil": ["soft", "sofft"]}}, ["grid.soil[1]", "'sofft'", "not a soil preset", "soft"]),
        ({"grid": {"vehicle": ["thalys", "tgv"]}}, ["grid.vehicle[1]", "'tgv'", "not a vehicle preset"]),
        ({"settings": {"load": "100e3"}}, ["settings.load", "a study does not vary", "clm simulate --vehicle"]),
        ({"settings": {"kf": 5e6}}, ["settings.kf", "'soil.kf'"]),
        ({"grid": {"speed": 60}}, ["grid.speed", "60", "expected a list"]),
        ({"grid": {"speed": []}}, ["grid.speed", "at least one value"]),
        ({"grid": {"seed": {"range": [5, 5]}}}, ["grid.seed.range", "no values"]),
        ({"grid": {"speed": {"linspace": [20, 150]}}}, ["grid.speed.linspace", "3 numbers"]),
        ({"sample": {"n": 0, "seed": 1, "vary": {"seed": {"integers": [0, 9]}}}}, ["sample.n", "0", ">= 1"]),
        ({"sample": {"n": 5, "vary": {"seed": {"integers": [0, 9]}}}}, ["sample.seed", "None", "seeded"]),
        ({"sample": {"n": 5, "seed": 1, "vary": {"speed": {"gauss": [1, 2]}}}}, ["sample.vary.speed", "uniform"]),
        ({"sample": {"n": 5, "seed": 1, "vary": {"speed": {"uniform": [90, 40]}}}},
         ["sample.vary.speed.uniform", "[90, 40]", "low < high"]),
        ({"grid": {"speed": [40]}, "settings": {"speed": 60}}, ["speed", "both fixed", "varied"]),
        ({"settings": {"defects": ["crack:x=3"]}}, ["defects", "crack"]),
        ({"runs": 3}, ["unknown key", "runs", "settings, grid, sample"]),
    ],
)
def test_bad_study_files_are_refused_naming_key_value_and_rule(data: dict[str, object], words: list[str]) -> None:
    with pytest.raises(ParameterError) as info:
        parse_study(data, "bad.yaml").cases()
    msg = str(info.value)
    assert msg.startswith("bad.yaml")
    for w in words:
        assert w in msg, (w, msg)


def test_sampled_value_outside_its_range_is_refused_with_the_case() -> None:
    spec = parse_study({"sample": {"n": 50, "seed": 3, "vary": {"speed": {"normal": [140, 20]}}}}, "s.yaml")
    with pytest.raises(ParameterError, match=r"s.yaml: case \d+ \(speed = .*\): speed = .*must be 0 to 150 m/s"):
        spec.cases()


def test_case_key_depends_on_every_resolved_setting_not_on_how_it_is_given() -> None:
    a = parse_study({"grid": {"speed": [60]}}).cases()[0]
    b = parse_study({"settings": {"speed": 60.0, "dt": 1e-4}}).cases()[0]  # dt: the default, given explicitly
    c = parse_study({"settings": {"speed": 60.0, "dt": 2e-4}}).cases()[0]
    assert a.key == b.key != c.key


def test_simulate_argv_is_the_same_run() -> None:
    case = parse_study({"settings": {"duration": 0.5, "soil.kf": 5.5e6, "train": ["power_car", "trailer_end"],
                                     "defects": ["dipped-joint:x=5,depth=0.001"], "n_sleepers": 81},
                        "grid": {"speed": [61.5]}}).cases()[0]
    argv = simulate_argv(case.settings)
    assert argv[:3] == ["simulate", "--vehicle", "thalys"]
    text = " ".join(argv)
    for part in ("--duration 0.5", "--set kf=5500000.0", "--train power_car,trailer_end",
                 "--defect dipped-joint:x=5,depth=0.001", "--sleepers 81", "--speed 61.5"):
        assert part in text


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.yaml")))
def test_shipped_examples_are_valid(name: str) -> None:
    spec = load_study(EXAMPLES / name)
    cases = spec.cases()
    assert cases
    if name == "smoke.yaml":
        assert len(cases) <= 8 and all(c.settings["duration"] <= 0.2 for c in cases)


def test_numbers_without_exponent_sign_are_numbers(tmp_path: Path) -> None:
    # PyYAML reads 5e6 and 2.5e6 as strings (YAML 1.1); a study reads them as numbers, as YAML 1.2 does
    f = tmp_path / "s.yaml"
    f.write_text("settings:\n  soil.kf: 5e6\n  duration: 2e-1\n"
                 "sample:\n  n: 3\n  seed: 1\n  vary:\n    soil.kc: {loguniform: [7.5e6, 3e7]}\n")
    cases = load_study(f).cases()
    assert cases[0].settings["soil.kf"] == 5e6 and cases[0].settings["duration"] == 0.2
    assert all(7.5e6 <= c.values["soil.kc"] <= 3e7 for c in cases)
    with pytest.raises(ParameterError, match=r"settings.duration = 'fast': must be a real number"):
        parse_study({"settings": {"duration": "fast"}}, "s").cases()
