"""Helpers for the ROS 2 tests: isolated DDS domains and ROS subprocesses.

Every test that talks over DDS gets its own ``ROS_DOMAIN_ID`` (held with a
file lock, so concurrent pytest runs on one machine never share a domain)
and discovery restricted to loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST``): no traffic leaves the machine.

Fixtures
--------
ros_domain_id : int
    A domain id no other test on this machine is using right now.
ros_env : dict
    Environment for ROS subprocesses (domain id, LOCALHOST discovery, RMW,
    unbuffered output; ``clm_ros`` is installed, editable, by scripts/bootstrap.sh).
ros_python : RosPython
    Starts python snippets as separate processes with ``ros_env`` and
    kills what is left of them at teardown.
new_ros_python : callable
    Returns another ``RosPython`` in a further domain of its own (to check
    isolation between domains).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import pytest
from clm_ros import processes
from clm_ros.errors import ClmRosError

from tests.clitools import wait_or_stacks

REPO_ROOT = Path(__file__).resolve().parents[2]


def pytest_configure(config: pytest.Config) -> None:
    """``CLM_REQUIRE_ROS=1`` (scripts/test.sh, hence CI): a missing ROS environment is an error, not skipped tests."""
    if os.environ.get("CLM_REQUIRE_ROS") == "1":
        try:
            import clm_msgs.msg  # noqa: F401
            import rclpy  # noqa: F401
        except ImportError as exc:
            raise pytest.UsageError(
                f"CLM_REQUIRE_ROS=1 but the ROS environment is missing ({exc}); run scripts/setup_ros.sh VENV"
            ) from exc

#: Domain ids handed out to tests (shared allocator with the demo and benchmarks).
DOMAIN_IDS = processes.DOMAIN_IDS

#: How long a test waits for DDS discovery before failing [s]. Discovery is
#: usually < 0.3 s, sometimes ~3 s on a loaded machine.
DISCOVERY_TIMEOUT = 20.0


#: The longest test files first, so that the xdist workers (scripts/test.sh: ``--dist loadfile``, files handed out
#: in collection order) end together instead of one running a minute-long file alone at the end (longest
#: processing time first). Measured: the sum of each file's test times, in the per-test table of
#: ``scripts/stress-tests.sh`` (2026-12-04, 3 workers: 86, 68, 62, 55, 30, 30 s; every other file under 25 s).
#: Only the order changes; a file missing here keeps its place after them.
LONGEST_FILES = ("test_calibration_node.py", "test_vehicle_node.py", "test_harness.py", "test_fleet.py",
                 "test_track_node_realtime.py", "test_packaging.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test under tests/ros with ``ros``; put the :data:`LONGEST_FILES` first (stable otherwise)."""
    here = Path(__file__).resolve().parent
    for item in items:
        if here in Path(str(item.path)).resolve().parents:
            item.add_marker(pytest.mark.ros)
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(Path(str(item.path)).name, len(rank)))


@contextlib.contextmanager
def hold_domain_id() -> Iterator[int]:
    """Hold a ROS domain id exclusively (the allocator of :mod:`clm_ros.processes`)."""
    try:
        with processes.hold_domain_id() as domain_id:
            yield domain_id
    except ClmRosError as exc:
        pytest.fail(str(exc))


@pytest.fixture
def ros_domain_id() -> Iterator[int]:
    """A ROS domain id no other test on this machine uses during this test."""
    with hold_domain_id() as domain_id:
        yield domain_id


def make_ros_env(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """:func:`clm_ros.processes.ros_env`: isolated on loopback in ``domain_id``."""
    return processes.ros_env(domain_id, base)


@pytest.fixture
def ros_env(ros_domain_id: int) -> dict[str, str]:
    """Environment for ROS subprocesses of this test (own domain, loopback only)."""
    return make_ros_env(ros_domain_id)


class RosPython:
    """Run python snippets as separate processes of the test's interpreter.

    The snippet is dedented and written to a file in the test's ``tmp_path``
    (so tracebacks show its line numbers); ``sys.argv[1:]`` are ``args``.
    Processes still running at teardown are killed.
    """

    #: How long to wait for DDS discovery before failing [s].
    discovery_timeout = DISCOVERY_TIMEOUT

    def __init__(self, env: Mapping[str, str], tmp_path: Path, domain_id: int) -> None:
        self.env = dict(env)
        self.domain_id = domain_id
        self.tmp_path = tmp_path
        self.procs: list[subprocess.Popen[str]] = []
        self._count = 0

    def _script(self, code: str, name: str) -> Path:
        self._count += 1
        path = self.tmp_path / f"{self._count:02d}_{name}.py"
        path.write_text(textwrap.dedent(code), encoding="utf-8")
        return path

    def spawn(self, code: str, args: Sequence[str] = (), *, name: str = "snippet") -> subprocess.Popen[str]:
        """Start ``code`` in a new process; stdout and stderr are pipes (text)."""
        script = self._script(code, name)
        proc = subprocess.Popen(
            [sys.executable, str(script), *args],
            env=self.env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=self.tmp_path,
        )
        self.procs.append(proc)
        return proc

    def run(
        self,
        code: str,
        args: Sequence[str] = (),
        *,
        name: str = "snippet",
        timeout: float = 60.0,
        check: bool = True,
    ) -> subprocess.CompletedProcess[str]:
        """Run ``code`` to completion; fail the test on a non-zero exit if ``check``."""
        proc = self.spawn(code, args, name=name)
        out, err = self.wait(proc, timeout)
        result = subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
        if check and proc.returncode != 0:
            pytest.fail(f"{name} exited with {proc.returncode}\n--- stdout\n{out}\n--- stderr\n{err}")
        return result

    @staticmethod
    def wait(proc: subprocess.Popen[str], timeout: float) -> tuple[str, str]:
        """Wait for ``proc``; on timeout fail the test with its threads' stacks and its output
        (:func:`tests.clitools.wait_or_stacks`)."""
        return wait_or_stacks(proc, timeout, f"process {proc.args!r}")

    def cleanup(self) -> None:
        """Kill the processes this helper started that are still running."""
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            try:
                proc.communicate(timeout=10)
            except (subprocess.TimeoutExpired, ValueError):
                pass


@pytest.fixture
def ros_python(ros_env: dict[str, str], ros_domain_id: int, tmp_path: Path) -> Iterator[RosPython]:
    """Helper to run python snippets as ROS processes in this test's domain."""
    helper = RosPython(ros_env, tmp_path, ros_domain_id)
    try:
        yield helper
    finally:
        helper.cleanup()


@pytest.fixture
def new_ros_python(tmp_path: Path) -> Iterator[Callable[[], RosPython]]:
    """Factory of ``RosPython`` helpers, each in a further domain of its own."""
    with contextlib.ExitStack() as stack:
        helpers: list[RosPython] = []

        def make() -> RosPython:
            domain_id = stack.enter_context(hold_domain_id())
            sub = tmp_path / f"domain_{domain_id}"
            sub.mkdir()
            helper = RosPython(make_ros_env(domain_id), sub, domain_id)
            helpers.append(helper)
            return helper

        try:
            yield make
        finally:
            for helper in helpers:
                helper.cleanup()
