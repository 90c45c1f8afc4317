"""The track node's data path: serialized wheel loads in, serialized answers published, over the online edge.

:class:`AnswerPath` is plain Python (no rclpy): the node hands it the bytes
taken from its subscription and the calls that publish serialized bytes; it
runs the one decode -> process -> encode path of the node, ``clm replay`` and
the fleet's offline check (:mod:`clm_core.online.edge`: :func:`decode`,
:func:`respond`, each answer's two messages serialized when read), so the
node's answers are bit for bit those of the offline replay. Around it: the
node's counters (:class:`clm_ros.diagnostics.Counters`), the lag of each
answer (:class:`clm_ros.diagnostics.LagMonitor`), the rejections logged once
per cause (:class:`clm_ros.node_log.NodeLog`, counted by the model), every
``publish_every``-th accepted message answered, the monitored sleepers, and
the data path's wall and CPU time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from clm_core.errors import ClmError
from clm_core.io.messages import encode_wheel_loads
from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, Reason, Rejected, ResponseFrame
from clm_core.online.edge import Answer, decode, respond
from clm_ros.diagnostics import Counters, LagMonitor
from clm_ros.node_log import NodeLog
from clm_ros.track_views import MonitoredSleepers

__all__ = ["AnswerPath", "Send", "raw_sender", "warm_up"]

#: A call that publishes serialized bytes (a publisher's ``publish_raw``, or ``publish``).
Send = Callable[[bytes], None]


class AnswerPath:
    """Decode, integrate, encode and publish one chunk of wheel-load messages at a time, in order.

    Parameters
    ----------
    model : OnlineTrackModel
        The configured model (its counters, ``model.stats``, are the node's for its life).
    counters : Counters
        The node's counters (received, published, internal errors, ...).
    lag : LagMonitor
        Collects the lag of every answer published.
    log : NodeLog
        The node's log (rejections once per cause, defects once).
    frame_id : str
        ``header.frame_id`` of the answers.
    every : int
        Answer every ``every``-th accepted message (1: all).
    monitor : MonitoredSleepers, optional
        Sleepers published as fixed series (topic ``monitored_sleepers``).
    """

    def __init__(self, model: OnlineTrackModel, counters: Counters, lag: LagMonitor, log: NodeLog,
                 frame_id: str = "track", every: int = 1, monitor: MonitoredSleepers | None = None) -> None:
        self.model = model
        self.counters = counters
        self.lag = lag
        self.log = log
        self.frame_id = frame_id
        self.every = int(every)
        self.monitor = monitor
        self.last_response: ResponseFrame | None = None
        self.new_stream = False  # set by the input: the next chunk starts a new stream (the state restarts)
        self.busy_s = 0.0  # wall time in the data path [s]
        self.cpu_s = 0.0  # CPU time of the executor thread in the data path [s]

    def reject(self, reason: Reason, text: str) -> None:
        """Refuse a message the edge never saw (``second_source``): counted by the model, logged once per cause."""
        self._rejected(self.model.reject(reason, text))

    def _rejected(self, r: Rejected) -> None:
        self.log.reject(r.reason.value, f"wheel loads rejected ({r.reason.value}): {r}", count=False)

    def run(self, raws: list[bytes], send_s: Send, send_w: Send, send_mon: Send | None = None) -> None:
        """Answer the serialized ``clm_msgs/WheelLoads`` messages ``raws``, in order.

        Parameters
        ----------
        raws : list of bytes
            The messages (CDR), as taken from the subscription.
        send_s, send_w : callable
            Publish a serialized ``SleeperResponse`` / ``WheelRailResponse``.
        send_mon : callable, optional
            Publish the serialized monitored sleepers (None: none monitored).
        """
        w0, c0 = time.perf_counter(), time.thread_time()
        c, model = self.counters, self.model
        c.received += len(raws)
        c.batches += 1
        c.largest_batch = max(c.largest_batch, len(raws))
        frames, refused = decode(model, raws, "wheel_loads", c.received - len(raws) + 1)
        for pre in refused:
            if pre is not None:
                self._rejected(pre)
        if not frames:
            return
        if self.new_stream:
            self.new_stream = False
            if model.last_stamp_ns is not None:
                self.model = model = model.renewed()
                self.log.info("wheel_loads: a new stream (its source left or went quiet): the state restarts")
        self.lag.waiting(len(frames), frames[0].stamp_ns)
        try:
            results = respond(model, frames, [None] * len(frames), self.frame_id)
        except Exception as exc:  # a defect of the model: the frames are lost, counted, logged once
            c.internal_errors += len(frames)
            self.log.error(f"internal error on {len(frames)} wheel-load message(s) (counted): {exc!r}",
                           key="internal_error")
            self.lag.waiting(0, 0)
            return
        stamps = self._publish(results, model.stats.accepted, send_s, send_w, send_mon)
        c.published += len(stamps)
        self.lag.answered(stamps)
        self.lag.waiting(0, 0)
        self.busy_s += time.perf_counter() - w0
        self.cpu_s += time.thread_time() - c0

    def _publish(self, results: list[Answer | Rejected], accepted: int, send_s: Send, send_w: Send,
                 send_mon: Send | None) -> list[int]:
        """Publish the answers (every ``every``-th accepted message's); the stamps of those published [ns]."""
        every, mon, fid = self.every, self.monitor, self.frame_id
        n = accepted - sum(1 for r in results if not isinstance(r, Rejected))  # accepted before this chunk
        stamps: list[int] = []
        for r in results:
            if isinstance(r, Rejected):
                self._rejected(r)
                continue
            n += 1
            self.last_response = r.response
            if every > 1 and n % every:
                continue
            try:
                send_s(r.sleeper_response)
                send_w(r.wheel_rail_response)
                if send_mon is not None and mon:
                    send_mon(mon.encode(r.stamp_ns, fid, r.response))
            except Exception as exc:  # a context going down, a middleware error: counted, never fatal
                self.counters.publish_failed += 1
                self.log.warning(f"an answer could not be published (counted as publish_failed): {exc}",
                                 key="publish_failed")
                continue
            stamps.append(r.stamp_ns)
        return stamps


def warm_up(model: OnlineTrackModel, frame_id: str = "track") -> list[ResponseFrame]:
    """Run ``model`` (a throw-away copy of the node's) over a few messages through the whole edge: every kernel
    compiled (or loaded from numba's on-disk cache), every operator factorised, the codec's paths taken, before
    the node is activated. Returns the responses (for the views to warm up on).

    Raises
    ------
    ClmError
        A warm-up message was refused (the configuration cannot answer a plain train).
    """
    x = 10.0 * model.params.track.spacing
    raws = [encode_wheel_loads(NS + k * 10**6, "warm-up", [0, 1], [x + 0.08 * k, x - 2.5 + 0.08 * k], [8e4, 8e4])
            for k in range(4)]
    out: list[ResponseFrame] = []
    for chunk in (raws[:1], raws[1:]):  # one message alone, then a batch: both paths of process_batch
        frames, refused = decode(model, chunk)
        for r in respond(model, frames, refused, frame_id):
            if isinstance(r, Rejected):
                raise ClmError(f"warm-up frame refused: {r}")
            r.sleeper_response, r.wheel_rail_response  # noqa: B018  # serialized: the encoders compiled
            out.append(r.response)
    return out


def raw_sender(pub: Any) -> Send:
    """The call that publishes serialized bytes on the lifecycle publisher ``pub``: while it is enabled, its
    rclpy publisher's ``publish_raw`` (what ``LifecyclePublisher.publish`` ends in, without its per-call
    wrapper, handle guard and type checks: ~1.5 us a message each); else ``pub.publish`` (which drops).

    Taken once per chunk in the executor thread, the thread that also destroys the publishers."""
    inner = getattr(pub, "_Publisher__publisher", None)
    if inner is None or not pub.is_activated:
        return pub.publish  # type: ignore[no-any-return]
    return inner.publish_raw  # type: ignore[no-any-return]
