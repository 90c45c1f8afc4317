"""One settings table per layer: the core's (clm_core.settings) and the ROS nodes' own (clm_ros.parameters).

The core's table holds what the core runs; the nodes' settings (real time,
diagnostics, views, the vehicle node's schedule of trains, clm demo's and
clm fleet's options) are the table of ``clm_ros.parameters``, of the same
Setting kind: complete, valid defaults, no name in both, found by
``lookup``, the defaults of the demo's parameter file, the options of the ROS
commands, and light enough for ``clm --help`` (no rclpy at import).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

from clm_ros.parameters import NODE_SETTINGS, TRACK_NODE_SETTINGS, lookup

from clm_core.online.model import FACTORY_SETTINGS
from clm_core.settings import SETTINGS

ROOT = Path(__file__).resolve().parents[2]
DEMO_YAML = ROOT / "ros2_ws" / "src" / "clm_ros" / "config" / "demo.yaml"
#: The settings that moved from the core's table to the nodes' (issue 22), and the one from readiness.py.
MOVED = ("rate", "closed_loop", "lag_budget", "realtime_priority", "max_feedback_delay", "monitored_sleepers",
         "monitored_positions", "markers_period", "trains", "headway", "train_pause", "track_node",
         "answer_timeout", "exit_when_done", "domain_id", "fleet_trains", "fleet_first_index", "start_signal")


def test_the_nodes_table_is_complete_and_apart_from_the_cores() -> None:
    assert set(MOVED) <= set(NODE_SETTINGS) and not set(MOVED) & set(SETTINGS)
    assert not set(NODE_SETTINGS) & set(SETTINGS)  # one home per setting
    for name, s in NODE_SETTINGS.items():
        assert s.name == name and s.unit and s.description, name
        assert s.check(s.default) == s.default, name
        assert lookup(name) is s
    assert lookup("dt") is SETTINGS["dt"] and lookup("track.kb").unit == "N/m"  # the core's, through the one lookup
    # the track node declares the model factory's settings and its own: every one found, none in both lists
    assert not set(TRACK_NODE_SETTINGS) & set(FACTORY_SETTINGS)
    assert all(lookup(n) for n in (*TRACK_NODE_SETTINGS, *FACTORY_SETTINGS))


def test_the_demo_parameter_file_uses_the_node_defaults() -> None:
    params = yaml.safe_load(DEMO_YAML.read_text())
    flat: dict[str, object] = {}
    for section in params.values():
        flat.update(section["ros__parameters"])
    unknown = [n for n in flat if n not in SETTINGS and n not in NODE_SETTINGS]
    assert not unknown, unknown
    checked = 0
    for name, value in flat.items():
        if name in NODE_SETTINGS:
            want = NODE_SETTINGS[name].default
            assert value == (pytest.approx(want) if isinstance(value, float) else want), (name, value)
            checked += 1
    assert checked >= 10


def test_ros_command_options_come_from_the_nodes_table() -> None:
    from clm_ros.commands import demo, fleet, view

    sub = argparse.ArgumentParser().add_subparsers()
    for mod in (demo, fleet, view):
        mod.register(sub)
    for cmd, names in (("demo", ("rate", "closed_loop", "domain_id", "realtime_priority")),
                       ("fleet", ("fleet_trains", "fleet_first_index", "rate", "domain_id")), ("view", ("domain_id",))):
        by_dest: dict[str, argparse.Action] = {}
        for a in sub.choices[cmd]._actions:
            by_dest.setdefault(a.dest, a)  # the setting's option (a hidden synonym such as --open-loop follows)
        for name in names:
            s = NODE_SETTINGS[name]
            assert s.description.replace("%", "%%") in (by_dest[name].help or ""), (cmd, name)
            assert set(by_dest[name].option_strings) >= set(s.option_strings), (cmd, name)
    args = sub.choices["fleet"].parse_args(["--trains", "3"])
    assert (args.fleet_trains, args.fleet_first_index, args.rate) == (3, 0, NODE_SETTINGS["rate"].default)


def test_the_table_imports_no_rclpy() -> None:
    """``clm --help`` builds the ROS commands' options from the table: it must stay light."""
    code = ("import json, sys\nimport clm_ros.parameters, clm_ros.run_settings\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
