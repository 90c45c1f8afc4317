"""Bag input of the calibration: formats, channel maps, and a clear error for every bad bag.

Broken bags are built in ``tmp_path`` from a small synthetic impact test
(5 areas, 1 kHz, 0.5 s): truncated and garbage files, missing topics,
clipped signals, gappy / jittered / reordered stamps, unknown units, too
short records. Each must give a BagError or CalibrationError whose message
names the topic (or file) and the value, never a traceback from rosbags.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from clm_core.calibration import BagError, CalibrationError, calibrate, read_bag
from clm_core.calibration.channels import load_channel_map, parse_channel_map
from clm_core.calibration.signals import Signal
from clm_core.errors import InputError
from clm_core.params import load_soil
from clm_core.synthetic import SyntheticRecord, add_noise, simulate_impact, write_bag

TOPIC = "/soil/area_p01"


@pytest.fixture(scope="module")
def record() -> SyntheticRecord:
    return add_noise(simulate_impact(load_soil("mevergnies"), n_areas=5, duration=0.5, hit_times=(0.1,)), 30.0, 7)


def _with(rec: SyntheticRecord, topic: str, **change: np.ndarray) -> SyntheticRecord:
    resp = tuple(replace(s, **change) if s.spec.topic == topic else s for s in rec.responses)
    return replace(rec, responses=resp)


def _read(bag) -> object:  # type: ignore[no-untyped-def]
    return read_bag(bag.path, load_channel_map(bag.channels))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_good_bag_reads_back_what_was_written(record: SyntheticRecord, tmp_path: Path, storage: str) -> None:
    bag = write_bag(record, tmp_path / "ok", storage=storage)  # type: ignore[arg-type]
    got = read_bag(bag.path, load_channel_map(bag.channels)).recording
    assert got.fs == pytest.approx(1000.0, rel=1e-9)
    k = [c.topic for c in got.channels].index(TOPIC)
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    np.testing.assert_allclose(got.responses[:, k], src.values, rtol=1e-12, atol=0)
    np.testing.assert_allclose(got.force, record.force.values, rtol=1e-12, atol=0)  # type: ignore[union-attr]


@pytest.mark.parametrize("style", ["float64", "block"])
def test_plain_std_msgs_styles(record: SyntheticRecord, tmp_path: Path, style: str) -> None:
    """std_msgs/Float64 per sample (log-time stamps) and Float64MultiArray blocks with a sample_rate."""
    bag = write_bag(record, tmp_path / style, style=style)  # type: ignore[arg-type]
    cmap = load_channel_map(bag.channels)
    if style == "block":
        assert cmap.channels[0].sample_rate == 1000.0
    got = read_bag(bag.path, cmap).recording
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    k = [c.topic for c in got.channels].index(TOPIC)
    np.testing.assert_allclose(got.responses[:, k], src.values, rtol=1e-12)


def test_block_messages_need_a_sample_rate(record: SyntheticRecord, tmp_path: Path) -> None:
    bag = write_bag(record, tmp_path / "blk", style="block")
    data = yaml.safe_load(bag.channels.read_text())
    for ch in data["channels"]:
        del ch["sample_rate"]
    with pytest.raises(BagError, match=r"blocks of 100 samples; give 'sample_rate'"):
        read_bag(bag.path, parse_channel_map(data))


def test_a_bare_mcap_file_and_units_other_than_si(record: SyntheticRecord, tmp_path: Path) -> None:
    """mm/s on the geophones and kN on the hammer: converted to SI on reading."""
    resp = tuple(replace(s, spec=replace(s.spec, units="mm/s", factor=1e-3)) for s in record.responses)
    force = replace(record.force, spec=replace(record.force.spec, units="kN", factor=1e3))  # type: ignore[arg-type]
    bag = write_bag(replace(record, responses=resp, force=force), tmp_path / "mm")
    assert "units: mm/s" in bag.channels.read_text()
    mcap = next(bag.path.glob("*.mcap"))
    got = read_bag(mcap, load_channel_map(bag.channels)).recording
    np.testing.assert_allclose(got.force, record.force.values, rtol=1e-12)  # type: ignore[union-attr]
    np.testing.assert_allclose(got.responses[:, 0], record.responses[0].values, rtol=1e-12)


def test_channels_at_another_rate_and_offset_are_resampled(record: SyntheticRecord, tmp_path: Path) -> None:
    """A response at 500 Hz, another 0.3 samples late: brought onto the force's 1 kHz grid."""
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    half = Signal(src.spec, src.t[::2], src.values[::2])
    other = record.responses[0]
    late = Signal(other.spec, other.t + 0.3e-3, other.values)
    rec = replace(record, responses=tuple(half if s is src else late if s is other else s for s in record.responses))
    got = _read(write_bag(rec, tmp_path / "rates")).recording  # type: ignore[attr-defined]
    assert got.fs == pytest.approx(1000.0)
    assert any("resampled from 500 Hz" in n for n in got.notes)
    assert any("shifted" in n for n in got.notes)


# --------------------------------------------------------------------------- broken bags


@pytest.mark.parametrize("storage,ext", [("mcap", "mcap"), ("sqlite3", "db3")])
@pytest.mark.parametrize("keep", [0.0, 0.5, 0.97])
def test_truncated_bag_file(record: SyntheticRecord, tmp_path: Path, storage: str, ext: str, keep: float) -> None:
    bag = write_bag(record, tmp_path / "t", storage=storage)  # type: ignore[arg-type]
    f = next(bag.path.glob(f"*.{ext}"))
    data = f.read_bytes()
    f.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(BagError, match=r"cannot be opened: .*truncated, corrupt") as exc:
        calibrate(bag.path, "impact")
    assert str(bag.path) in str(exc.value)
    assert isinstance(exc.value, InputError)


def test_not_a_bag(tmp_path: Path, record: SyntheticRecord) -> None:
    with pytest.raises(BagError, match="does not exist"):
        read_bag(tmp_path / "nothing", parse_channel_map({"force": {"topic": "/f", "units": "N"},
                                                          "channels": [{"topic": "/x", "area": 0, "quantity":
                                                                        "velocity", "units": "m/s"}]}))
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file" * 10)
    bag = write_bag(record, tmp_path / "ok")
    with pytest.raises(BagError, match="File magic is invalid"):
        read_bag(junk, load_channel_map(bag.channels))
    (bag.path / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9")
    with pytest.raises(BagError, match="cannot be opened: Could not load YAML"):
        read_bag(bag.path, load_channel_map(bag.channels))


def test_missing_topic(record: SyntheticRecord, tmp_path: Path) -> None:
    rec = replace(record, responses=tuple(s for s in record.responses if s.spec.topic != TOPIC))
    bag = write_bag(rec, tmp_path / "m")
    cmap = load_channel_map(bag.channels).to_dict()
    cmap["channels"].append({"topic": TOPIC, "area": 1, "quantity": "velocity", "units": "m/s"})
    with pytest.raises(BagError, match=rf"topic\(s\) {TOPIC} not in the bag .*topics in the bag: /hammer/force"):
        read_bag(bag.path, parse_channel_map(cmap))


def test_clipped_signal(record: SyntheticRecord, tmp_path: Path) -> None:
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    limit = 0.15 * np.max(src.values)  # a sensor range far too small for the hit
    bag = write_bag(_with(record, TOPIC, values=np.minimum(src.values, limit)), tmp_path / "c")
    with pytest.raises(BagError, match=rf"topic {TOPIC}: clipped record \(flat top\): \d+ samples at the "
                       rf"maximum {limit:g} \(SI\)"):
        calibrate(bag.path, "impact")


def test_clipping_at_a_declared_full_scale(record: SyntheticRecord, tmp_path: Path) -> None:
    bag = write_bag(record, tmp_path / "fs")
    data = yaml.safe_load(bag.channels.read_text())
    peak = float(np.max(np.abs(record.force.values)))  # type: ignore[union-attr]
    data["force"]["full_scale"] = 0.9 * peak
    with pytest.raises(BagError, match=r"topic /hammer/force: clipped record: \d+ sample\(s\) at or beyond the sensor "
                       r"full scale"):
        read_bag(bag.path, parse_channel_map(data))


def test_gappy_stamps(record: SyntheticRecord, tmp_path: Path) -> None:
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    keep = np.ones(src.t.size, dtype=bool)
    keep[200:205] = False  # 5 dropped messages
    bag = write_bag(_with(record, TOPIC, t=src.t[keep], values=src.values[keep]), tmp_path / "g")
    with pytest.raises(BagError, match=rf"topic {TOPIC}: gappy stamps: 1 gap\(s\), the first of 0.006 s after "
                       r"t = 0.199000 s .*about 5 sample\(s\) missing"):
        calibrate(bag.path, "impact")


def test_jittered_stamps(record: SyntheticRecord, tmp_path: Path) -> None:
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    rng = np.random.default_rng(0)
    t = src.t + rng.uniform(-0.4e-3, 0.4e-3, src.t.size)  # reception-time stamps, +-0.4 intervals
    bag = write_bag(_with(record, TOPIC, t=t), tmp_path / "j")
    with pytest.raises(BagError, match=rf"topic {TOPIC}: jittered stamps: sample \d+ .* intervals\) from the uniform "
                       r"grid of 0.00\d+ s \(rule: within 0.25 intervals\)"):
        calibrate(bag.path, "impact")
    # the same stamps pass with a looser rule
    res = calibrate(bag.path, "impact", {"sampling": {"jitter_tol": 0.45}, "compare": False})
    assert res.parameters


def test_duplicated_stamps(record: SyntheticRecord, tmp_path: Path) -> None:
    src = next(s for s in record.responses if s.spec.topic == TOPIC)
    t = src.t.copy()
    t[101] = t[100]
    bag = write_bag(_with(record, TOPIC, t=t), tmp_path / "r")
    with pytest.raises(BagError, match=rf"topic {TOPIC}: duplicated stamps: sample 101 has the stamp t = 0.100000 s"):
        calibrate(bag.path, "impact")


def test_unknown_unit(record: SyntheticRecord, tmp_path: Path) -> None:
    bag = write_bag(record, tmp_path / "u")
    data = yaml.safe_load(bag.channels.read_text())
    data["channels"][1]["units"] = "furlong/fortnight"
    bag.channels.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match=r"channels\[1\] \(/soil/area_m01\): unknown unit "
                       r"'furlong/fortnight' for a velocity; allowed: m/s, mm/s"):
        calibrate(bag.path, "impact")


def test_channel_map_errors(tmp_path: Path) -> None:
    good = {"force": {"topic": "/f", "units": "N"}, "channels": [{"topic": "/x", "area": 0, "quantity": "velocity",
                                                                   "units": "m/s"}]}
    parse_channel_map(good)
    cases = [
        ({**good, "extra": 1}, r"unknown key\(s\) \['extra'\]"),
        ({**good, "channels": [{"topic": "x", "area": 0, "quantity": "velocity", "units": "m/s"}]},
         "must be a string starting with '/'"),
        ({**good, "channels": [{"topic": "/x", "area": 0, "quantity": "speed", "units": "m/s"}]},
         "quantity = 'speed'"),
        ({**good, "channels": [{"topic": "/x", "area": 0, "sleeper": 1, "quantity": "velocity", "units": "m/s"}]},
         "exactly one of 'area'"),
        ({**good, "channels": [{"topic": "/x", "area": 0, "quantity": "velocity"}]}, "'units' missing"),
        ({**good, "channels": [good["channels"][0], {**good["channels"][0], "topic": "/y"}]},
         "both measure the velocity of area 0"),
        ({**good, "force": {"topic": "/f", "units": "kg"}}, "unknown unit 'kg' for a force"),
        ({**good, "format": "v0"}, "this version reads"),
    ]
    for data, msg in cases:
        with pytest.raises(CalibrationError, match=msg):
            parse_channel_map(data)  # type: ignore[arg-type]
    with pytest.raises(CalibrationError, match="not found"):
        load_channel_map(tmp_path / "none.yaml")


def test_too_short_record(tmp_path: Path) -> None:
    rec = add_noise(simulate_impact(load_soil("mevergnies"), n_areas=3, duration=0.12, hit_times=(0.05,)), 30.0)
    bag = write_bag(rec, tmp_path / "short")
    with pytest.raises(CalibrationError, match=r"too short a record: segments of 0.0\d+ s after each hit give \d+ "
                       r"frequency lines in 2-150 Hz \(rule: at least 16"):
        calibrate(bag.path, "impact")
    tiny = add_noise(simulate_impact(load_soil("mevergnies"), n_areas=3, duration=0.04, hit_times=(0.01,)), 30.0)
    bag = write_bag(tiny, tmp_path / "tiny")
    with pytest.raises(BagError, match=r"too short a record: 40 samples \(rule: at least 64\)"):
        calibrate(bag.path, "impact")


def test_missing_channel_map_and_wrong_test(record: SyntheticRecord, tmp_path: Path) -> None:
    bag = write_bag(record, tmp_path / "nomap")
    text = bag.channels.read_text()
    bag.channels.unlink()
    with pytest.raises(CalibrationError, match="no channel map: give --channels"):
        calibrate(bag.path, "impact")
    other = tmp_path / "map.yaml"
    other.write_text(text.replace("test: impact", "test: receptance"))
    with pytest.raises(CalibrationError, match="is for the receptance test, not the impact test"):
        calibrate(bag.path, "impact", {"channels": str(other)})
