"""The import contract: ``clm_core`` never imports the ROS layer, its layers hold, and ``clm --help`` stays light.

Two independent checks of the first rule:

- ruff's ``flake8-tidy-imports`` banned-api rule (TID251, configured in
  pyproject.toml) over every file of ``clm_core``, imports inside functions
  included; a probe file shows the rule is really active;
- every module of ``clm_core`` imported in a fresh interpreter, after which no
  ROS module may be loaded.

The layers of ``clm_core`` (:data:`tests.codeshape.LAYERS`, bottom first:
errors/checks, io (time base, codec, bags, files), params/settings,
soil/track, solver, online/vehicle, calibration/halfspace, freefield, outputs
(history files, figures, reports), synthetic, studies, commands): no module
imports a unit of a higher layer, at import time, inside a function (lazy) or
under ``TYPE_CHECKING``; an AST scan of every file, nothing imported, and no
exception list (issue 22 split ``io`` into ``io`` and ``outputs``: 13 known
upward imports then, none now).

The third rule (the parser imports no heavy module) is checked by what is
imported, not by timing (the machine is shared): ``clm --help`` took 1.8-4.6 s
when building the parser imported numba, scipy.signal and matplotlib.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests import codeshape

ROOT = Path(__file__).resolve().parents[1]
ROS_MODULES = ("clm_ros", "clm_msgs", "rclpy", "rcl_interfaces", "rosidl_runtime_py", "builtin_interfaces",
               "std_msgs", "sensor_msgs", "diagnostic_msgs", "rosgraph_msgs", "lifecycle_msgs", "launch",
               "launch_ros", "rpyutils")
#: Not imported while the parser is built (clm_ros itself is: its commands register through an entry point).
HEAVY_MODULES = ("numba", "scipy", "matplotlib", "rosbags", "tqdm", *(m for m in ROS_MODULES if m != "clm_ros"))


def _ruff() -> list[str]:
    exe = Path(sys.executable).parent / "ruff"
    if exe.is_file():
        return [str(exe)]
    if shutil.which("ruff"):
        return ["ruff"]
    pytest.skip("ruff not installed (pip install -e .[dev])")


def test_ruff_bans_ros_imports_in_the_core() -> None:
    proc = subprocess.run([*_ruff(), "check", "--select", "TID251", "--output-format", "concise", "clm_core"],
                          cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # the rule is active for clm_core: a probe that imports rclpy inside a function is reported
    probe = "def f() -> None:\n    import rclpy  # a core module must not do this\n"
    proc = subprocess.run([*_ruff(), "check", "--select", "TID251", "--stdin-filename", "clm_core/_probe.py", "-"],
                          cwd=ROOT, input=probe, capture_output=True, text=True)
    assert proc.returncode == 1 and "TID251" in proc.stdout and "rclpy" in proc.stdout, proc.stdout


def test_no_core_module_imports_ros() -> None:
    code = (
        "import importlib, json, pkgutil, sys\n"
        "import clm_core\n"
        "names = sorted(m.name for m in pkgutil.walk_packages(clm_core.__path__, 'clm_core.'))\n"
        "for n in names:\n"
        "    importlib.import_module(n)\n"
        f"ros = sorted(m for m in sys.modules if m.split('.')[0] in {ROS_MODULES!r})\n"
        "print(json.dumps({'modules': names, 'ros': ros}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(out["modules"]) > 50 and "clm_core.settings" in out["modules"]
    assert out["ros"] == []


def test_cli_parser_imports_no_heavy_module() -> None:
    code = (
        "import json, sys\n"
        "from clm_core.cli import build_parser\n"
        "p = build_parser()\n"
        "cmds = sorted(next(a for a in p._actions if a.dest == 'command').choices)\n"
        f"heavy = sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY_MODULES!r}))\n"
        "print(json.dumps({'commands': cmds, 'heavy': heavy}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert {"simulate", "receptance", "report", "calibrate", "soil-calibrate", "soil-chain"} <= set(out["commands"])
    assert out["heavy"] == []


def test_every_unit_of_the_core_is_in_a_layer() -> None:
    units = {codeshape.unit_of(m) for m, _ in codeshape.modules()} - {""}
    assert len(units) > 20
    for u in units:
        codeshape.layer_of(u)  # KeyError names a unit the table does not place


def test_no_upward_import_between_the_layers_of_the_core() -> None:
    found = [str(i) for i in codeshape.upward_imports()]
    assert found == [], "upward imports (a lower layer importing a higher one):\n" + "\n".join(found)


#: Peers of one layer that stay independent (neither imports the other): the half-space is calibrated by the
#: synthetic references and ``clm soil-calibrate``, not by ``calibration``; the online model and the vehicle meet
#: only in the nodes.
APART = (("halfspace", "calibration"), ("online", "vehicle"))


def test_independent_peers_do_not_import_each_other() -> None:
    pairs = {frozenset(p) for p in APART}
    found = [str(i) for i in codeshape.imports()
             if frozenset((codeshape.unit_of(i.module), codeshape.unit_of(i.target))) in pairs]
    assert found == [], "\n".join(found)


def test_io_is_the_bottom_of_the_edges() -> None:
    """``io`` (time base, codec, bags, files) imports nothing of the core but the bottom layer; nothing of it
    is left that draws or writes results (those live in ``outputs``)."""
    io_imports = {codeshape.unit_of(i.target) for i in codeshape.imports() if codeshape.unit_of(i.module) == "io"}
    assert io_imports <= {"io", *codeshape.LAYERS[0]}, io_imports
    names = {m for m, _ in codeshape.modules() if codeshape.unit_of(m) == "io"}
    assert not {"clm_core.io.history", "clm_core.io.plots", "clm_core.io.report_index"} & names


def test_the_layer_scan_sees_lazy_relative_and_type_only_imports() -> None:
    """A probe in the solver importing studies lazily, calibration relatively, vehicle for typing, outputs by
    ``importlib.import_module``: all four upward; an import of a lower layer (track) or of its own unit is not."""
    probe = ("from typing import TYPE_CHECKING\n"
             "from clm_core.track import TrackSystem\n"
             "from . import window\n"
             "from ..calibration import api\n"
             "if TYPE_CHECKING:\n    from clm_core.vehicle.coupled import CoupledResult\n"
             "def f():\n    import clm_core.studies.engine\n"
             "def g():\n    import importlib\n    return importlib.import_module('clm_core.outputs.plots')\n")
    found = codeshape.upward_imports(codeshape.probe_imports("clm_core.solver.probe", probe))
    assert sorted((codeshape.unit_of(i.target), i.in_function, i.type_only) for i in found) == [
        ("calibration", False, False), ("outputs", True, False), ("studies", True, False), ("vehicle", False, True)]
