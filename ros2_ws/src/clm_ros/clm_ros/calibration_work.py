"""One calibration as the calibration node's worker thread runs it: checks, the fit with progress, the push.

:func:`run_job` never raises: every failure of a request (bad bag, path,
method, options nested too deeply for the parser, a fit that cannot be done,
a refused push) becomes a :class:`clm_ros.calibration_goal.CalibrationOutcome`
with its reason. A cancel or a shutdown stops the fit at its next progress
report (:class:`CalibrationStopped`, raised from the progress callback).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from clm_core.calibration import BagError, CalibrationError, calibrate
from clm_core.calibration.options import METHODS
from clm_core.errors import ClmError
from clm_ros.calibration_goal import ABORTED, CANCELED, SUCCEEDED, CalibrationOutcome, check_paths, failed, fit_message
from clm_ros.calibration_jobs import Job
from clm_ros.calibration_push import PushOutcome, one_line, push_values

#: Share of the feedback fraction given to the fit when a push follows.
FIT_SHARE_WITH_PUSH = 0.9
#: Least time between two feedback messages of one stage [s] (a new stage is sent at once; a cancel is checked at
#: every progress report, sent or not).
FEEDBACK_PERIOD = 0.1

#: ``feedback(job, stage, fraction, message)``: publish a goal's feedback.
Feedback = Callable[[Job, str, float, str], None]
#: ``push(values, target)``: set the fitted parameters on a running node.
Push = Callable[[dict[str, float], str], PushOutcome]


class CalibrationStopped(BaseException):
    """Raised inside a running fit (from its progress callback) on cancel or shutdown.

    A ``BaseException`` so that no ``except Exception`` on the way swallows it.
    """


def run_job(job: Job, roots: tuple[Path, ...], stop: threading.Event, feedback: Feedback, push: Push,
            log: Any, on_start: Callable[[], None]) -> CalibrationOutcome:
    """One calibration (worker thread): checks, the fit with feedback, the push. Never raises.

    Parameters
    ----------
    job : Job
    roots : tuple of Path
        ``allowed_roots``: where the bag, parameter file and channel map may lie.
    stop : threading.Event
        Set at shutdown: the fit stops at its next progress report.
    feedback : callable
        Publishes the goal's feedback (stage, fraction 0 to 1, message).
    push : callable
        Sets the fitted parameters on the target node.
    log : NodeLog
        The node's log (:class:`clm_ros.node_log.NodeLog`).
    on_start : callable
        Called once the checks passed, before the fit (the node's ``/diagnostics``).
    """
    req = job.request
    if req.error:
        return failed(ABORTED, req.error, req)
    if not req.bag:
        return failed(ABORTED, "bag_path is empty: give the bag directory or .mcap/.db3 file", req)
    if req.method not in METHODS:
        return failed(ABORTED, f"method = {req.method!r}: must be one of {', '.join(METHODS)}", req)
    refused = check_paths(req, roots)  # under allowed_roots, exists, regular files only (no FIFO)
    if refused:
        return failed(ABORTED, refused, req)
    share = FIT_SHARE_WITH_PUSH if req.push else 1.0
    log.info(f"{job.label}: calibrating: {req.method} on {req.bag!r}")
    on_start()
    sent = -math.inf

    def progress(stage: str, frac: float) -> None:
        nonlocal sent
        if stop.is_set():
            raise CalibrationStopped("node shutting down")
        if job.cancel_requested():
            raise CalibrationStopped("canceled")
        now = time.monotonic()
        if stage != job.stage or frac >= 1.0 or now - sent >= FEEDBACK_PERIOD:
            sent = now
            feedback(job, stage, share * frac, "")

    try:
        result = calibrate(Path(req.bag).expanduser(), req.method, req.options, progress=progress,
                           allow_partial=req.allow_partial)
    except CalibrationStopped as why:
        if str(why) == "canceled":
            return failed(CANCELED, f"canceled during '{job.stage}' ({100 * job.fraction:.0f} %)", req)
        return failed(ABORTED, f"node shutting down: stopped during '{job.stage}'", req)
    except BagError as exc:
        return failed(ABORTED, f"bag refused: {exc}", req)
    except ClmError as exc:  # CalibrationError (options, channel map, band), ParameterError
        return failed(ABORTED, f"calibration failed: {exc}", req)
    except RecursionError:
        return failed(ABORTED, "calibration failed: the options are nested too deeply (Python's recursion "
                      f"limit, {sys.getrecursionlimit()}, reached while reading them)", req)
    except Exception as exc:  # the node must survive anything a bag can trigger
        log.exception(f"{job.label}: unexpected {type(exc).__name__} in the calibration")
        return failed(ABORTED, f"calibration failed with an unexpected {type(exc).__name__}: {exc} "
                      "(traceback in the node's log)", req)
    fit_text = fit_message(result)
    if not req.push:
        return CalibrationOutcome(SUCCEEDED, one_line(fit_text), result, None, req.context())
    if job.cancel_requested() or stop.is_set():
        canceled = job.cancel_requested()
        reason = "canceled" if canceled else "node shutting down"
        return CalibrationOutcome(CANCELED if canceled else ABORTED,
                                  one_line(f"{reason} after the fit, before the push: nothing pushed ({fit_text})"),
                                  result, None, req.context())
    feedback(job, "pushing", share, f"pushing the fitted parameters to {req.target}")
    try:
        outcome = push(push_values(result), req.target)
    except CalibrationError as exc:
        outcome = PushOutcome(target=req.target, service="", accepted=False, reason=str(exc))
    if outcome.accepted:
        feedback(job, "done", 1.0, f"pushed {len(outcome.values)} parameter(s) to {outcome.target}")
        msg = f"{fit_text}; pushed {len(outcome.values)} parameter(s) to {outcome.target}"
        return CalibrationOutcome(SUCCEEDED, one_line(msg), result, outcome, req.context())
    msg = (f"fit succeeded but the push to {outcome.target or repr(req.target)} failed: {outcome.reason} "
           f"({fit_text}; fitted parameters in the result)")
    return CalibrationOutcome(ABORTED, one_line(msg), result, outcome, req.context())
