"""Packaging of clm_ros for users with a full ROS 2 install (``ros2 run``, ``ros2 launch``).

``launch``/``launch_ros`` are not installable here, so the launch files are
checked without them:

- they compile and define ``generate_launch_description``; run against
  recording stand-ins of the ``launch``/``launch_ros`` classes, they start the
  packaged executables (console scripts of setup.py) under the node names of
  ``config/demo.yaml``, use only declared launch arguments, and their
  substitutions evaluate to what is meant (default parameter file, the
  vehicle's subscriber count with and without the recorder, topic names in a
  namespace);
- every parameter in ``config/demo.yaml`` is declared by its node and applied:
  each node is started as a process with ``--ros-args --params-file
  config/demo.yaml`` and read back over its parameter services (the track
  node, which autostarts, also in a namespace, and must be active and
  publish ``/diagnostics``; the vehicle node with a short duration and a
  subscriber created here, whose messages are counted);
- ``colcon list`` types clm_ros as ros.ament_python and clm_msgs as
  ros.ament_cmake (a catkin_pkg validation failure would silently make it
  plain python); setup.cfg's script directories follow the ament convention,
  and ``colcon build`` of a copy puts the executables in ``lib/clm_ros`` and
  the launch and config files in ``share/clm_ros``;
- a pip install (a wheel, as ``pip install -e`` builds) puts the console
  scripts in the environment's ``bin/`` and the data files in
  ``share/clm_ros`` (setup.py's docstring says so; ``python -m
  clm_ros.track_node`` is the documented way in the venv and is what the node
  tests here run).
"""

from __future__ import annotations

import ast
import configparser
import importlib.util
import json
import math
import os
import py_compile
import shutil
import stat
import subprocess
import sys
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from clm_ros.processes import ros_args

REPO = Path(__file__).resolve().parents[2]
WS = REPO / "ros2_ws"
PKG = WS / "src" / "clm_ros"
LAUNCH = PKG / "launch"
CONFIG = PKG / "config" / "demo.yaml"
LAUNCH_FILES = sorted(LAUNCH.glob("*.launch.py"))
VENV_BIN = Path(sys.executable).parent
TIMEOUT = 20.0  # discovery / service readiness [s]
START_TIMEOUT = 90.0  # a node process importing numba and building its model on a loaded machine [s]
TRACK_NODE = "clm_track_node"
VEHICLE_NODE = "clm_vehicle_node"


# ---------------------------------------------------------------------------------------------- helpers


def setup_kwargs() -> dict[str, Any]:
    """The keyword arguments setup.py passes to setuptools.setup (run in the package dir, as colcon/pip do)."""
    code = (
        "import json, setuptools, sys\n"
        "keys = ('name', 'version', 'data_files', 'entry_points')\n"
        "setuptools.setup = lambda **kw: print(json.dumps({k: kw[k] for k in keys}))\n"
        "sys.argv = ['setup.py']\n"
        "exec(compile(open('setup.py').read(), 'setup.py', 'exec'), {'__name__': '__main__'})\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=PKG, capture_output=True, text=True, timeout=60, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def console_scripts() -> dict[str, str]:
    entries = setup_kwargs()["entry_points"]["console_scripts"]
    return {name.strip(): target.strip() for name, target in (e.split("=", 1) for e in entries)}


def demo_params() -> dict[str, dict[str, Any]]:
    """Parameters of each node from config/demo.yaml: ``/**`` merged with the node's own section."""
    data = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
    common = data.get("/**", {}).get("ros__parameters", {})
    out: dict[str, dict[str, Any]] = {}
    for key, section in data.items():
        if key == "/**":
            continue
        node = key.rsplit("/", 1)[-1]
        out[node] = {**common, **section["ros__parameters"]}
    return out


# ---------------------------------------------------------------------------------------------- launch files


def test_launch_files_exist_compile_and_define_generate_launch_description(tmp_path: Path) -> None:
    assert {p.name for p in LAUNCH_FILES} >= {"demo.launch.py", "track.launch.py", "replay.launch.py"}
    for path in LAUNCH_FILES:
        py_compile.compile(str(path), cfile=str(tmp_path / (path.name + "c")), doraise=True)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        funcs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description"]
        assert len(funcs) == 1 and not funcs[0].args.args, f"{path.name}: generate_launch_description() missing"


class _Rec:
    """Stand-in for a launch/launch_ros class: records its arguments."""

    kind = "?"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def _stub_modules() -> dict[str, types.ModuleType]:
    def make(name: str, *classes: str) -> types.ModuleType:
        mod = types.ModuleType(name)
        for c in classes:
            setattr(mod, c, type(c, (_Rec,), {"kind": c}))
        return mod

    mods = {
        "launch": make("launch", "LaunchDescription"),
        "launch.actions": make("launch.actions", "DeclareLaunchArgument", "EmitEvent", "ExecuteProcess",
                               "RegisterEventHandler", "GroupAction", "IncludeLaunchDescription", "OpaqueFunction",
                               "LogInfo", "SetEnvironmentVariable", "TimerAction", "Shutdown"),
        "launch.conditions": make("launch.conditions", "IfCondition", "UnlessCondition"),
        "launch.event_handlers": make("launch.event_handlers", "OnProcessExit", "OnProcessStart", "OnShutdown"),
        "launch.events": make("launch.events", "Shutdown"),
        "launch.substitutions": make("launch.substitutions", "LaunchConfiguration", "PathJoinSubstitution",
                                     "PythonExpression", "TextSubstitution", "EnvironmentVariable"),
        "launch_ros": make("launch_ros"),
        "launch_ros.actions": make("launch_ros.actions", "Node", "LifecycleNode", "PushRosNamespace"),
        "launch_ros.parameter_descriptions": make("launch_ros.parameter_descriptions", "ParameterValue",
                                                  "ParameterFile"),
        "launch_ros.substitutions": make("launch_ros.substitutions", "FindPackageShare"),
    }
    return mods


def _perform(sub: Any, ctx: dict[str, str]) -> str:
    """Evaluate a (stand-in) substitution as launch would, with launch arguments ``ctx``."""
    if isinstance(sub, str):
        return sub
    if isinstance(sub, (list, tuple)):
        return "".join(_perform(s, ctx) for s in sub)
    kind = getattr(sub, "kind", None)
    if kind == "LaunchConfiguration":
        return ctx[sub.args[0]]
    if kind == "TextSubstitution":
        return str(sub.kwargs.get("text", sub.args[0] if sub.args else ""))
    if kind == "PathJoinSubstitution":
        return os.path.join(*[_perform(s, ctx) for s in sub.args[0]])
    if kind == "FindPackageShare":
        assert sub.args[0] == "clm_ros"
        return str(PKG)  # the installed share/clm_ros mirrors the source package's launch/ and config/
    if kind == "PythonExpression":
        return str(eval(_perform(sub.args[0], ctx)))
    raise AssertionError(f"unexpected substitution {sub!r}")


class _Context:
    """Stand-in of launch's LaunchContext for an OpaqueFunction: the launch arguments (KeyError if undeclared)."""

    def __init__(self, values: dict[str, str]) -> None:
        self.launch_configurations = values


def _launch(path: Path, monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    for name, mod in _stub_modules().items():
        monkeypatch.setitem(sys.modules, name, mod)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    ld = module.generate_launch_description()
    assert ld.kind == "LaunchDescription"
    return list(ld.args[0])


def _walk(obj: Any) -> Iterator[Any]:
    """Every stand-in object reachable from ``obj``."""
    if isinstance(obj, _Rec):
        yield obj
        for v in (*obj.args, *obj.kwargs.values()):
            yield from _walk(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _walk(v)
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _walk(v)


def _arguments(entities: list[Any]) -> dict[str, Any]:
    return {e.args[0]: e.kwargs.get("default_value") for e in entities if e.kind == "DeclareLaunchArgument"}


def _run(entities: list[Any], **over: str) -> list[Any]:
    """The launch as launch runs it with arguments ``over``: declared defaults, then the OpaqueFunctions' actions."""
    declared = _arguments(entities)
    assert all(v is not None for v in declared.values()), "every launch argument needs a default"
    unknown = set(over) - set(declared)
    assert not unknown, f"not launch arguments: {unknown}"
    ctx = {k: _perform(v, {}) for k, v in declared.items()} | over
    used = {o.args[0] for o in _walk(entities) if o.kind == "LaunchConfiguration"}
    assert used <= set(declared), f"launch configurations used but not declared: {used - set(declared)}"
    out: list[Any] = []
    for e in entities:
        if e.kind == "OpaqueFunction":
            out += e.kwargs["function"](_Context(dict(ctx)))  # a KeyError: an argument used but not declared
        elif e.kind != "DeclareLaunchArgument":
            out.append(e)
    scripts = console_scripts()
    for n in (e for e in _walk(out) if e.kind in ("Node", "LifecycleNode")):
        assert n.kwargs["package"] == "clm_ros"
        assert n.kwargs["executable"] in scripts, f"{n.kwargs['executable']} is not a console script of setup.py"
    return out


def _nodes(actions: list[Any]) -> dict[str, Any]:
    return {n.kwargs["executable"]: n for n in actions if n.kind == "Node"}


def _params(node: Any) -> tuple[str, dict[str, Any]]:
    """(parameter file, the dictionary that follows it) of a node."""
    file, values = node.kwargs["parameters"]
    return file, values


COMMON = {"namespace", "use_sim_time", "params_file", "track", "soil", "model", "wheel_loads_topic",
          "sleeper_response_topic", "wheel_rail_response_topic", "log_level"}


def test_track_launch_file(monkeypatch: pytest.MonkeyPatch) -> None:
    entities = _launch(LAUNCH / "track.launch.py", monkeypatch)
    assert COMMON | {"autostart", "node_name"} <= set(_arguments(entities))
    (track,) = _run(entities)
    assert track.kwargs["executable"] == "track_node" and track.kwargs["name"] == TRACK_NODE
    assert track.kwargs["namespace"] == "" and track.kwargs["remappings"] == []
    assert _params(track) == (str(CONFIG), {"use_sim_time": False, "autostart": True})
    assert TRACK_NODE in demo_params()
    (track,) = _run(entities, params_file="/x/mine.yaml", autostart="false", namespace="/line1/", soil="haren",
                    use_sim_time="true", wheel_loads_topic="/simulator/wheel_loads", node_name="track_a")
    assert _params(track) == ("/x/mine.yaml", {"soil": "haren", "use_sim_time": True, "autostart": False})
    assert track.kwargs["namespace"] == "/line1" and track.kwargs["name"] == "track_a"
    assert track.kwargs["remappings"] == [("wheel_loads", "/simulator/wheel_loads")]
    assert track.kwargs["ros_arguments"] == ["--log-level", "info"]


def test_demo_launch_file(monkeypatch: pytest.MonkeyPatch) -> None:
    entities = _launch(LAUNCH / "demo.launch.py", monkeypatch)
    assert COMMON | {"vehicle", "speed", "duration", "trains", "record", "bag"} <= set(_arguments(entities))
    actions = _run(entities)
    nodes = _nodes(actions)
    assert set(nodes) == {"track_node", "vehicle_node"}
    assert nodes["track_node"].kwargs["name"] == TRACK_NODE and nodes["vehicle_node"].kwargs["name"] == VEHICLE_NODE
    assert {TRACK_NODE, VEHICLE_NODE} <= set(demo_params())
    assert _params(nodes["track_node"]) == (str(CONFIG), {"use_sim_time": False, "monitored_sleepers": "100,200,300"})
    # one train, then the vehicle exits and the launch ends; it waits for the track node only
    assert _params(nodes["vehicle_node"]) == (str(CONFIG), {"use_sim_time": False, "trains": 1, "exit_when_done": True,
                                                            "wait_for_subscribers": 1, "publish_clock": False})
    assert not [a for a in actions if a.kind == "ExecuteProcess"]  # no recorder by default
    handlers = [a for a in actions if a.kind == "RegisterEventHandler"]
    assert len(handlers) == 1 and handlers[0].args[0].kwargs["target_action"] is nodes["vehicle_node"]
    assert handlers[0].args[0].kwargs["on_exit"][0].kwargs["event"].kind == "Shutdown"
    # with the recorder (it must see the first message), in a namespace, on sim time, other presets
    for ns, prefix in (("", ""), ("line1", "/line1"), ("/line1/", "/line1")):
        actions = _run(entities, record="true", namespace=ns, use_sim_time="true", soil="haren", vehicle="intercity",
                       speed="44.4", trains="3", sleeper_response_topic="answers")
        nodes = _nodes(actions)
        assert nodes["vehicle_node"].kwargs["namespace"] == nodes["track_node"].kwargs["namespace"] == prefix
        assert _params(nodes["track_node"])[1] == {"soil": "haren", "use_sim_time": True,
                                                   "monitored_sleepers": "100,200,300"}
        assert _params(nodes["vehicle_node"])[1] == {
            "soil": "haren", "use_sim_time": False, "vehicle": "intercity", "speed": 44.4, "trains": 3,
            "exit_when_done": True, "wait_for_subscribers": 2, "publish_clock": True}
        for n in nodes.values():
            assert n.kwargs["remappings"] == [("sleeper_response", "answers")]
        (rec,) = [a for a in actions if a.kind == "ExecuteProcess"]
        cmd = rec.kwargs["cmd"]
        assert cmd[:3] == ["ros2", "bag", "record"] and "--use-sim-time" in cmd
        assert cmd[cmd.index("--topics") + 1:] == [f"{prefix}/wheel_loads", f"{prefix}/answers",
                                                   f"{prefix}/wheel_rail_response", f"{prefix}/track_markers",
                                                   "/diagnostics"]
    # the demo defaults
    p = demo_params()
    assert p[VEHICLE_NODE]["vehicle"] == "thalys" and p[VEHICLE_NODE]["speed"] == pytest.approx(83.33)
    for node in (TRACK_NODE, VEHICLE_NODE):
        assert (p[node]["track"], p[node]["soil"], p[node]["model"]) == ("mevergnies", "mevergnies", "clm")
    assert p[TRACK_NODE]["dt"] == 1e-4 and p[TRACK_NODE]["n_sleepers"] == 61 and p[VEHICLE_NODE]["rate"] == 1000.0


def test_replay_launch_file(monkeypatch: pytest.MonkeyPatch) -> None:
    entities = _launch(LAUNCH / "replay.launch.py", monkeypatch)
    assert COMMON | {"bag", "rate", "out"} <= set(_arguments(entities))
    with pytest.raises(RuntimeError, match="give the bag"):
        _run(entities)
    actions = _run(entities, bag="/data/demo_bag")
    (track,) = _nodes(actions).values()
    assert track.kwargs["executable"] == "track_node" and _params(track) == (str(CONFIG), {"use_sim_time": False})
    (play,) = [a for a in actions if a.kind == "ExecuteProcess"]
    assert play.kwargs["cmd"] == ["ros2", "bag", "play", "/data/demo_bag", "--rate", "1.0", "--topics", "/wheel_loads"]
    (handler,) = [a for a in actions if a.kind == "RegisterEventHandler"]
    on_exit = handler.args[0].kwargs
    assert on_exit["target_action"] is play and on_exit["on_exit"][0].kind == "TimerAction"
    # in a namespace, on the bag's clock, with the answers recorded
    actions = _run(entities, bag="b", namespace="line1", use_sim_time="true", out="answers", rate="0.5")
    play, rec = [a for a in actions if a.kind == "ExecuteProcess"]
    assert play.kwargs["cmd"] == ["ros2", "bag", "play", "b", "--rate", "0.5", "--topics", "/wheel_loads", "--clock",
                                  "--remap", "/wheel_loads:=/line1/wheel_loads"]
    assert rec.kwargs["cmd"] == ["ros2", "bag", "record", "--storage", "mcap", "--output", "answers",
                                 "--use-sim-time", "--topics", "/line1/wheel_loads", "/line1/sleeper_response",
                                 "/line1/wheel_rail_response", "/diagnostics"]
    assert _params(_nodes(actions)["track_node"])[1] == {"use_sim_time": True}


def _field_type(ts: Any, msgtype: str, path: str) -> str:
    """Walk a Foxglove message path (``wheels[0].force``) through a type; the leaf's type name."""
    from rosbags.typesys.base import Nodetype

    current = ("msg", msgtype)
    for part in path.split("."):
        name, _, index = part.partition("[")
        assert current[0] == "msg", f"{path}: {name} below a {current}"
        fields = dict(ts.fielddefs[current[1]][1])
        assert name in fields, f"{path}: {current[1]} has no field {name!r} ({sorted(fields)})"
        kind, detail = fields[name]
        if kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
            assert index, f"{path}: {name} is a sequence, give an index"
            kind, detail = detail[0]
        else:
            assert not index, f"{path}: {name} is not a sequence"
        leaf = str(detail[0] if kind == Nodetype.BASE else detail)
        current = ("msg", detail) if kind == Nodetype.NAME else ("base", leaf)
    return current[1]


def test_foxglove_layout_of_the_demo() -> None:
    """config/foxglove_demo.json: a whole layout whose panels show topics the demo has, by valid message paths."""
    from clm_ros.launch_common import DEMO_MONITORED_SLEEPERS, LIVE_VIEWS
    from clm_ros.launcher import TOPICS as RECORDED

    TOPICS = {**RECORDED, **{f"/{t}": msgtype for t, msgtype in LIVE_VIEWS.items()}}  # live: the monitored series too

    from clm_core.io.messages import typestore

    layout = json.loads((PKG / "config" / "foxglove_demo.json").read_text(encoding="utf-8"))
    assert {"configById", "layout", "globalVariables", "userNodes", "playbackConfig"} <= set(layout)

    def leaves(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    panels = leaves(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"]), "every panel placed once, every placed panel configured"
    ts = typestore()
    plotted: list[str] = []
    for pid, cfg in layout["configById"].items():
        kind = pid.split("!")[0]
        if kind == "Plot":
            for p in cfg["paths"]:
                topic, _, path = p["value"].partition(".")
                assert topic in TOPICS, f"{pid}: {topic} is not a topic of the demo"
                leaf = _field_type(ts, TOPICS[topic], path)
                assert leaf in ("float64", "float32"), f"{pid}: {p['value']} is {leaf}, not a number to plot"
                plotted.append(p["value"])
            assert "[" in cfg["title"] and "]" in cfg["title"], f"{pid}: give the unit in the title"
        elif kind == "3D":
            assert set(cfg["topics"]) == {"/track_markers"} and "/track_markers" in TOPICS
        elif kind == "DiagnosticSummary":
            assert cfg["topicToRender"] == "/diagnostics"
        elif kind == "RawMessages":
            assert cfg["topicPath"] in TOPICS
        else:
            raise AssertionError(f"unexpected panel {pid}")
    assert "/wheel_loads.wheels[0].force" in plotted and "/monitored_sleepers.soil_force[0]" in plotted
    # the monitored series plotted are those the demo asks the track node for, in that order
    titles = " ".join(cfg.get("title", "") for cfg in layout["configById"].values())
    assert ", ".join(DEMO_MONITORED_SLEEPERS.split(",")) in titles
    n = len(DEMO_MONITORED_SLEEPERS.split(","))
    assert {f"/monitored_sleepers.soil_force[{i}]" for i in range(n)} <= set(plotted)


# ---------------------------------------------------------------------------------------------- nodes + demo.yaml

try:
    from clientnode import RESEND_QUERY, ClientNode
    from clm_msgs.msg import WheelLoads
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.srv import GetParameters
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    HAVE_ROS = True
except ImportError:  # the launch-file and packaging checks above and below still run
    HAVE_ROS = False
    ClientNode = object  # type: ignore[misc,assignment]  # Client serves only tests marked needs_ros

needs_ros = pytest.mark.skipif(not HAVE_ROS, reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")
#: rcl_interfaces/ParameterType -> field of ParameterValue
_VALUE_FIELD = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value"}


class Client(ClientNode):
    """In-process rclpy node in the test's domain, reading the nodes of other processes (exit 0 is fine)."""

    def __init__(self, domain_id: int, procs: list[subprocess.Popen[str]]) -> None:
        super().__init__(domain_id, procs, "clm_test_packaging_client", ok_exits=(0,), timeout=TIMEOUT)

    def call(self, srv_type: Any, name: str, request: Any, timeout: float | None = START_TIMEOUT,
             resend_after: float | None = None) -> Any:
        return super().call(srv_type, name, request, timeout, resend_after)

    def parameters(self, node: str, names: list[str]) -> dict[str, Any]:
        """Values of ``names`` on ``node``; None for a parameter the node does not declare."""
        res = self.call(GetParameters, f"{node}/get_parameters", GetParameters.Request(names=names),
                        resend_after=RESEND_QUERY)
        out: dict[str, Any] = {}
        for name, v in zip(names, res.values):
            out[name] = getattr(v, _VALUE_FIELD[v.type]) if v.type in _VALUE_FIELD else None
        return out


def _start(module: str, ros_env: dict[str, str], tmp_path: Path, *ros_args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", module, "--ros-args", "--params-file", str(CONFIG), *ros_args],
        env=ros_env, cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)


def _stop(procs: list[subprocess.Popen[str]]) -> dict[int, str]:
    outs: dict[int, str] = {}
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            outs[p.pid] = p.communicate(timeout=20)[0]
        except subprocess.TimeoutExpired:
            p.kill()
            outs[p.pid] = p.communicate()[0]
        except ValueError:  # output already read
            outs[p.pid] = ""
    return outs


def _assert_applied(expected: dict[str, Any], got: dict[str, Any], node: str) -> None:
    undeclared = sorted(k for k, v in got.items() if v is None)
    assert not undeclared, f"config/demo.yaml sets parameters {node} does not declare: {undeclared}"
    for k, v in expected.items():
        if isinstance(v, float):
            assert got[k] == pytest.approx(v, rel=1e-12) and isinstance(got[k], float), (node, k, got[k])
        else:
            assert got[k] == v and type(got[k]) is type(v), (node, k, got[k], v)


@pytest.fixture
def client(ros_domain_id: int) -> Iterator[tuple[Client, list[subprocess.Popen[str]]]]:
    procs: list[subprocess.Popen[str]] = []
    c = Client(ros_domain_id, procs)
    try:
        yield c, procs
    finally:
        c.close()
        _stop(procs)


@needs_ros
def test_track_node_takes_every_demo_parameter(client, ros_env: dict[str, str], tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    c, procs = client
    expected = demo_params()[TRACK_NODE]
    # plain, and in a namespace (the file's /**/clm_track_node section applies there too)
    procs.append(_start("clm_ros.track_node", ros_env, tmp_path))
    procs.append(_start("clm_ros.track_node", ros_env, tmp_path, "-r", "__ns:=/line1"))
    diags: list[Any] = []
    c.node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    for name in (f"/{TRACK_NODE}", f"/line1/{TRACK_NODE}"):
        _assert_applied(expected, c.parameters(name, sorted(expected)), name)
        state = c.state(name)
        assert state == "active", f"{name} autostart: {state}"
    # it runs: both publish diagnostics at the file's period
    c.wait_for(lambda: len(diags) >= 4, "/diagnostics of the track nodes", TIMEOUT)
    assert all(s.hardware_id == "clm_core" for d in diags for s in d.status)
    outs = _stop(procs)
    for p in procs:
        assert "configured: " in outs[p.pid] and "window 61 sleepers" in outs[p.pid], outs[p.pid]
        assert "dt = 0.0001 s" in outs[p.pid], outs[p.pid]


@needs_ros
def test_vehicle_node_takes_every_demo_parameter(client, ros_env: dict[str, str], tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    c, procs = client
    expected = demo_params()[VEHICLE_NODE]
    duration = 0.2
    # one short train; no track node (any reader will do, and the answers are not waited for long)
    over = {"duration": duration, "ack_timeout": 0.5, "trains": 1, "exit_when_done": True, "track_node": ""}
    proc = _start("clm_ros.vehicle_node", ros_env, tmp_path, *ros_args(over)[1:])
    procs.append(proc)
    got = c.parameters(f"/{VEHICLE_NODE}", sorted(expected))  # answered while it waits for a subscriber
    _assert_applied({**expected, **over}, got, VEHICLE_NODE)
    assert expected["wait_for_subscribers"] == 1
    msgs: list[Any] = []
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    c.node.create_subscription(WheelLoads, "/wheel_loads", msgs.append, qos)
    n = round(duration * expected["rate"]) + 1
    c.wait_for(lambda: len(msgs) >= n and proc.poll() is not None, f"{n} wheel-load messages and the node's exit",
               START_TIMEOUT)
    out = proc.communicate(timeout=20)[0]
    assert proc.returncode == 0, out
    assert len(msgs) == n and f"published {n} wheel-load messages at 1000.0 Hz" in out, out
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]
    assert all(b - a == round(1e9 / expected["rate"]) for a, b in zip(stamps, stamps[1:]))
    speeds = {w.speed for m in msgs for w in m.wheels}
    assert speeds == {expected["speed"]}  # Thalys at 83.33 m/s
    assert all(math.isfinite(w.force) and w.force > 0 for m in msgs for w in m.wheels)


# ---------------------------------------------------------------------------------------------- colcon / pip


def _colcon() -> Path:
    exe = VENV_BIN / "colcon"
    if not exe.exists():
        pytest.skip("colcon not installed in this environment (scripts/ros-requirements.txt has it)")
    return exe


def test_package_xml_and_colcon_list(tmp_path: Path) -> None:
    out = subprocess.run([str(_colcon()), "--log-base", str(tmp_path / "log"), "list", "--base-paths", str(WS / "src")],
                         capture_output=True, text=True, timeout=120, check=True).stdout
    kinds = {line.split()[0]: line.split()[-1] for line in out.splitlines() if line.strip()}
    assert kinds.get("clm_ros") == "(ros.ament_python)", out
    assert kinds.get("clm_msgs") == "(ros.ament_cmake)", out
    from catkin_pkg.package import parse_package

    pkg = parse_package(str(PKG / "package.xml"))
    pkg.validate()
    deps = {d.name for d in pkg.exec_depends}
    need = {"rclpy", "clm_msgs", "std_msgs", "builtin_interfaces", "diagnostic_msgs", "rosgraph_msgs",
            "rcl_interfaces", "lifecycle_msgs", "python3-numpy", "python3-scipy", "python3-yaml",
            "python3-matplotlib", "launch", "launch_ros"}
    assert need <= deps, need - deps
    assert pkg.version == setup_kwargs().get("version", pkg.version)


def test_setup_cfg_script_dirs_follow_ament() -> None:
    cfg = configparser.ConfigParser()
    cfg.read(PKG / "setup.cfg")
    # underscores: setuptools >= 58 rejects the old dashed spellings
    assert cfg["develop"]["script_dir"] == "$base/lib/clm_ros"
    assert cfg["install"]["install_scripts"] == "$base/lib/clm_ros"
    kw = setup_kwargs()
    assert kw["name"] == "clm_ros"
    assert console_scripts() == {
        "track_node": "clm_ros.track_node:main",
        "vehicle_node": "clm_ros.vehicle_node:main",
        "calibration_node": "clm_ros.calibration_node:main",
        "receiver_node": "clm_ros.receiver_node:main",
    }
    data = {dest: sorted(files) for dest, files in kw["data_files"]}
    assert data["share/clm_ros/launch"] == sorted(f"launch/{p.name}" for p in LAUNCH_FILES)
    assert data["share/clm_ros/config"] == ["config/demo.yaml", "config/foxglove_demo.json"]
    assert data["share/ament_index/resource_index/packages"] == ["resource/clm_ros"]
    for entry in console_scripts().values():
        module, func = entry.split(":")
        assert (PKG / (module.replace(".", "/") + ".py")).is_file()
        tree = ast.parse((PKG / (module.replace(".", "/") + ".py")).read_text(encoding="utf-8"))
        assert any(isinstance(n, ast.FunctionDef) and n.name == func for n in tree.body), entry
        assert 'if __name__ == "__main__":' in (PKG / (module.replace(".", "/") + ".py")).read_text()  # python -m


def _copy_package(tmp_path: Path) -> Path:
    src = tmp_path / "src" / "clm_ros"
    shutil.copytree(PKG, src, ignore=shutil.ignore_patterns("*.egg-info", "__pycache__", "build"))
    return src


def _assert_layout(prefix: Path, script_dir: Path) -> None:
    for name in ("track_node", "vehicle_node", "calibration_node"):
        exe = script_dir / name
        assert exe.is_file() and exe.stat().st_mode & stat.S_IXUSR, exe
    share = prefix / "share" / "clm_ros"
    assert {p.name for p in (share / "launch").glob("*.launch.py")} == {p.name for p in LAUNCH_FILES}
    assert (share / "config" / "demo.yaml").read_bytes() == CONFIG.read_bytes()
    assert (share / "package.xml").is_file()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "clm_ros").is_file()


def test_colcon_build_installs_the_ament_layout(tmp_path: Path) -> None:
    _copy_package(tmp_path)
    env = {k: v for k, v in os.environ.items() if k not in ("COLCON_HOME",)}
    res = subprocess.run(
        [str(_colcon()), "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(tmp_path / "src"),
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
         "--packages-select", "clm_ros", "--event-handlers", "console_direct-"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    prefix = tmp_path / "install" / "clm_ros"
    _assert_layout(prefix, prefix / "lib" / "clm_ros")  # where `ros2 run clm_ros track_node` looks
    assert not (prefix / "bin").exists()


def _installed_clm_ros() -> str | None:
    try:
        from importlib.metadata import distribution

        return str(distribution("clm_ros")._path)  # type: ignore[attr-defined]
    except Exception:
        return None


def test_pip_install_puts_scripts_in_bin_and_data_in_share(tmp_path: Path) -> None:
    before = _installed_clm_ros()
    src = _copy_package(tmp_path)
    # a wheel, as `pip install [-e]` builds it (build isolation: setuptools + wheel from the index or pip's cache)
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path / "whl"),
                          str(src)], capture_output=True, text=True, timeout=300)
    if res.returncode != 0:
        if any(s in res.stdout + res.stderr for s in ("NewConnectionError", "Could not find a version", "No matching")):
            pytest.skip(f"cannot build a wheel without the package index: {res.stderr.strip()[-300:]}")
        pytest.fail(res.stdout + res.stderr)
    wheel = next((tmp_path / "whl").glob("clm_ros-*.whl"))
    prefix = tmp_path / "prefix"
    # --ignore-installed: without it pip uninstalls the environment's own (editable) clm_ros first
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-compile", "--ignore-installed",
                    "--no-warn-script-location", "--prefix", str(prefix), str(wheel)],
                   capture_output=True, text=True, timeout=300, check=True)
    # pip ignores setup.cfg's script dirs: console scripts in bin/, as setup.py's docstring says
    _assert_layout(prefix, prefix / "bin")
    assert not (prefix / "lib" / "clm_ros").exists()
    assert _installed_clm_ros() == before  # the environment's own install untouched


# ---------------------------------------------------------------------------------------------- shipped demo bag

DEMO_BAG = REPO / "bags" / "demo" / "demo_bag"


def test_demo_bag_is_small_complete_and_replays_bit_for_bit(tmp_path: Path) -> None:
    import numpy as np
    from clm_ros.replay import replay_bag

    from clm_core.io.bags import BagReader
    from clm_core.io.timebase import stamp_ns
    from clm_core.online import OnlineTrackModel
    from clm_core.params import load_model

    size = sum(f.stat().st_size for f in DEMO_BAG.rglob("*") if f.is_file())
    assert size < 4e6, f"demo bag {size / 1e6:.1f} MB"
    meta = yaml.safe_load((DEMO_BAG / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap" and meta["ros_distro"] == "jazzy"
    assert counts["/wheel_loads"] == counts["/sleeper_response"] == counts["/wheel_rail_response"] == 1001
    # the track node's output is a function of its input: offline replay gives the recorded responses
    model = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=61)
    stats = replay_bag(DEMO_BAG, tmp_path / "out", model)
    assert stats.accepted == 1001 and not stats.rejected

    def responses(path: Path) -> dict[tuple[str, int], Any]:
        out = {}
        with BagReader(path) as reader:
            for bm in reader.messages(["/sleeper_response", "/wheel_rail_response"]):
                m = reader.deserialize(bm.data, bm.msgtype)
                out[(bm.topic, stamp_ns(m.header))] = m
        return out

    rec, rep = responses(DEMO_BAG), responses(tmp_path / "out")
    assert rec.keys() == rep.keys() and len(rec) == 2002
    for key, m in rec.items():
        fields = (("sleeper_index", "position", "soil_force", "rail_deflection", "sleeper_displacement",
                   "area_displacement") if key[0] == "/sleeper_response" else ("wheel_id", "position",
                                                                               "rail_deflection", "rail_velocity"))
        for f in fields:
            np.testing.assert_array_equal(np.asarray(getattr(m, f)), np.asarray(getattr(rep[key], f)), err_msg=f)
