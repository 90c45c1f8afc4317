"""clm_ros.node_log: the one logging helper of the nodes, on rclpy's real logger.

What it must do: a keyed message logged once (or at most once per period,
saying how many were suppressed), rejections counted per reason and logged
once per reason, every line bounded, and several severities from the one
helper without rclpy's "severity cannot be changed between calls" error (the
reason it keys by name, not by calling line).
"""

from __future__ import annotations

import doctest
import math
from collections import Counter

import pytest

pytest.importorskip("rclpy")

import rclpy
import rclpy.logging
from clm_ros import node_log
from clm_ros.node_log import LOG_LINE_LIMIT, NodeLog


def test_the_modules_examples_pass() -> None:
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    tests = [t for t in doctest.DocTestFinder().find(node_log, "clm_ros.node_log") if t.examples]
    assert tests
    for t in tests:
        runner.run(t)
    assert runner.summarize(verbose=False).failed == 0


def test_every_severity_and_key_through_rclpys_logger(capfd: pytest.CaptureFixture[str]) -> None:
    """rclpy's own logger (rcutils, to stderr): four severities from the helper's one call site each, keys
    honoured, lines cut to the limit, a traceback whole."""
    logger = rclpy.logging.get_logger("clm_node_log_test")
    logger.set_level(rclpy.logging.LoggingSeverity.DEBUG)
    t = [0.0]
    log = NodeLog(logger, now=lambda: t[0])
    for k in range(3):
        log.info(f"info line {k}")  # unkeyed: every one
        log.warning(f"warn once {k}", key="w")
        log.error(f"error throttled {k}", key="e", every=2.0)
        log.debug(f"debug {k}")
        t[0] += 1.0  # 0, 1, 2 s: the throttled error at 0 and 2
    log.rearm("w")
    assert log.warning("warn again", key="w")
    log.info("y" * 3 * LOG_LINE_LIMIT)
    try:
        raise RuntimeError("a defect " + "z" * 2 * LOG_LINE_LIMIT)
    except RuntimeError:
        assert log.exception("callback failed", key="defect")
        assert not log.exception("callback failed", key="defect")
    err = capfd.readouterr().err
    assert [f"info line {k}" in err for k in range(3)] == [True] * 3
    assert "warn once 0" in err and "warn once 1" not in err and "warn once 2" not in err
    assert "error throttled 0" in err and "error throttled 1" not in err
    assert "error throttled 2 (1 similar message suppressed)" in err
    assert "warn again (2 similar messages suppressed)" not in err  # rearm forgets what was suppressed
    assert "warn again" in err
    assert "debug 2" in err
    cut = next(line for line in err.splitlines() if "yyyy" in line)
    assert cut.endswith(f"... ({2 * LOG_LINE_LIMIT} more characters)")
    assert cut.count("y") < LOG_LINE_LIMIT
    assert "Traceback" in err and "z" * 2 * LOG_LINE_LIMIT in err  # the traceback is not cut
    assert err.count("callback failed") == 1


def test_rejections_are_counted_per_reason_and_logged_once_each(capfd: pytest.CaptureFixture[str]) -> None:
    log = NodeLog(rclpy.logging.get_logger("clm_node_log_rejections"))
    for _ in range(5):
        log.reject("busy", "goal refused: busy")
    log.reject("queue_full", "request refused: queue full")
    assert log.rejection_values() == {"rejected": 6, "rejected.busy": 5, "rejected.queue_full": 1}
    assert log.rejected_total == 6
    err = capfd.readouterr().err
    assert err.count("goal refused: busy") == 1 and err.count("queue full") == 1


def test_rejections_counted_elsewhere_are_only_logged() -> None:
    """The track node's model counts its refusals (OnlineStats.rejected): the log shares that counter."""
    counts: Counter[str] = Counter()
    log = NodeLog(rclpy.logging.get_logger("clm_node_log_shared"), rejections=counts)
    counts["malformed"] += 2  # the model counted two
    log.reject("malformed", "wheel loads rejected (malformed)", count=False)
    log.reject("second_source", "second source")  # the node's own
    assert log.rejection_values() == {"rejected": 3, "rejected.malformed": 2, "rejected.second_source": 1}
    assert counts["second_source"] == 1


def test_a_real_nodes_logger_is_taken_from_the_node(ros_domain_id: int) -> None:
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    try:
        node = rclpy.create_node("clm_node_log_node", context=ctx)
        log = NodeLog(node)
        assert log.warning("from a node", key="k", every=math.inf)
        assert not log.warning("from a node", key="k")
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
