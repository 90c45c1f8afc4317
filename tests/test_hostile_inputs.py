"""Hostile inputs to the core: unbounded override ranges, special files as bags, garbage metadata (issue 26, 7 and 10).

- a parameter file whose override range has no bound is refused before
  anything is allocated, with the bound in the message (it took the track node
  to 2.96 GB in 4 s); ``clm simulate --params`` says so in one line;
- ``clm calibrate /dev/zero`` and a FIFO named like a bag: one line, exit 2,
  nothing read (a FIFO read would block for ever);
- a garbage ``metadata.yaml``: one line; a parameter file nested too deeply
  for the YAML parser: one line.
"""

from __future__ import annotations

import os
import resource
import shutil
from pathlib import Path

import pytest

from clm_core.errors import ParameterError
from clm_core.io.bags import BagReader
from clm_core.io.errors import BagError
from clm_core.params import MAX_OVERRIDE_SLEEPERS, ModelParams, load_model
from tests.clitools import input_error, run_clm

REPO = Path(__file__).resolve().parents[1]
IMPACT_BAG = REPO / "bags" / "calibration" / "impact_mevergnies"


def _with_overrides(overrides: list[dict[str, object]]) -> dict[str, object]:
    return {**load_model("mevergnies", "mevergnies", "clm").to_dict(), "overrides": overrides}


@pytest.mark.parametrize(("overrides", "message"), [
    ([{"from": 0, "to": 10**11, "kb": 4.7e6}], "to = 100000000000: must be within +-1000000000"),
    ([{"from": 0, "to": 10**8, "kb": 4.7e6}], f"spans 100000001 sleepers: at most {MAX_OVERRIDE_SLEEPERS} sleepers"),
    ([{"from": 0, "to": 900_000, "kb": 4.7e6}, {"from": 0, "to": 900_000, "kf": 2e7}],
     f"more than {MAX_OVERRIDE_SLEEPERS} sleepers in all (at entry 2)"),
    ([{"sleepers": "all", "kb": 4.7e6}], "must be a list of sleeper indices"),
    ([{"sleepers": [1.5], "kb": 4.7e6}], "must be an integer sleeper index"),
    ({"from": 0}, "overrides must be a list of mappings"),
])
def test_unbounded_override_refused_with_its_bound(overrides: list[dict[str, object]], message: str) -> None:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(ParameterError, match=message.replace("+", r"\+").replace("(", r"\(").replace(")", r"\)")):
        ModelParams.from_dict(_with_overrides(overrides))
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grown_mb < 200, grown_mb  # refused before the range was expanded (10**8 indices: > 3 GB)


def test_bounded_override_still_taken() -> None:
    p = ModelParams.from_dict(_with_overrides([{"from": 10, "to": 20, "kb": 4.7e6}, {"sleepers": [3], "kf": 2e7}]))
    assert p.overrides[0].sleepers == tuple(range(10, 21)) and p.overrides[1].sleepers == (3,)


def test_simulate_params_unbounded_is_one_line(tmp_path: Path) -> None:
    import yaml

    f = tmp_path / "unbounded.yaml"
    f.write_text(yaml.safe_dump(_with_overrides([{"from": 0, "to": 10**10, "kb": 4.7e6}])))
    proc = run_clm(["simulate", "--params", str(f), "--out", str(tmp_path / "out")])
    assert proc.returncode == 2 and "MemoryError" not in proc.stderr, proc.stderr
    assert "must be within +-1000000000" in input_error(proc)
    deep = tmp_path / "deep.yaml"
    deep.write_text("a: " + "[" * 3000 + "]" * 3000)
    proc = run_clm(["simulate", "--params", str(deep), "--out", str(tmp_path / "out")])
    assert proc.returncode == 2 and "nested too deeply" in input_error(proc), proc.stderr


def test_special_files_are_never_read_as_bags(tmp_path: Path) -> None:
    fifo = tmp_path / "blocking.mcap"
    os.mkfifo(fifo)
    for path, what in ((Path("/dev/zero"), "a device"), (fifo, "a FIFO")):
        with pytest.raises(BagError, match=f"not a rosbag2 bag \\({what}"):
            BagReader(path)
    bag = tmp_path / "bag"
    shutil.copytree(IMPACT_BAG, bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.unlink()
    os.mkfifo(mcap)
    with pytest.raises(BagError, match=f"{mcap.name} is a FIFO, not a regular file"):
        BagReader(bag)
    for target in ("/dev/zero", str(fifo)):
        proc = run_clm(["calibrate", target, "--method", "impact", "--out", str(tmp_path / "out"),
                        "--channels", str(IMPACT_BAG / "channels.yaml")])
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert "not a rosbag2 bag" in input_error(proc)


@pytest.mark.parametrize("garbage", ["a: b: c\n  - d\n\t: e\n", "rosbag2_bagfile_information: 7\n",
                                     "\x00\x01 garbage [\n", "- [\n" * 50])
def test_garbage_metadata_is_one_line(tmp_path: Path, garbage: str) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(IMPACT_BAG, bag)
    (bag / "metadata.yaml").write_text(garbage)
    with pytest.raises(BagError, match="cannot be opened") as info:
        BagReader(bag)
    assert "\n" not in str(info.value)
    proc = run_clm(["calibrate", str(bag), "--method", "impact", "--out", str(tmp_path / "out"), "--no-plots"],
                   )
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
