"""The one logging helper of the clm nodes: bounded lines, once-only and throttled messages, counted rejections.

Every clm node (track, vehicle, calibration) logs through a :class:`NodeLog`
made from its node::

    self.log = NodeLog(self)
    self.log.info("configured")
    self.log.warning(f"publish failed (counted): {exc}", key="publish_failed")   # once for the node's life
    self.log.warning(f"no answer for {t:g} s", key="silent", every=5.0)          # at most once per 5 s
    self.log.rearm("silent")                                                       # the next one is logged again
    self.log.reject("busy", f"goal rejected: {reason}")                             # counted, logged once per reason
    self.log.rejection_values()     # {"rejected": 3, "rejected.busy": 3}: the /diagnostics key-values

Why a helper of its own rather than rclpy's ``once=`` / ``throttle_duration_sec=``:
rclpy keys those by the *calling line*, so a helper called from many places
would share one key, and it refuses a second severity from one line
(``ValueError: Logger severity cannot be changed between calls``). Here a
message is keyed by name, every line is cut to :data:`LOG_LINE_LIMIT`
characters (issue 12.8) and the logger is called from one line per severity.

Rejections (an input refused: a second source, a goal while busy, a malformed
message) are counted per reason and logged as a warning once per reason (the
count is in ``/diagnostics``; the log says the first time why). When another
counter already holds them (the track node's model counts its refusals in
:class:`clm_core.online.OnlineStats`), pass that ``Counter`` as
``rejections`` and call :meth:`NodeLog.reject` with ``count=False`` from the
paths where the model counted already.

Thread safety: the node's executor thread and a diagnostics thread may log at
the same time; the keys' bookkeeping is under a lock, the logger call outside
it.
"""

from __future__ import annotations

import math
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable
from typing import Any

__all__ = ["LOG_LINE_LIMIT", "NodeLog", "bounded"]

#: Longest log line [characters] (issue 12.8): longer texts are cut with a note of what was left out.
LOG_LINE_LIMIT = 400


def bounded(text: str, limit: int = LOG_LINE_LIMIT) -> str:
    """``text`` cut to at most ``limit`` characters (``... (N more characters)`` at the end when cut).

    Examples
    --------
    >>> bounded("short")
    'short'
    >>> line = bounded("x" * 100, 40)
    >>> len(line), line[-24:]
    (40, '... (60 more characters)')
    """
    if len(text) <= limit:
        return text
    note = f" ... ({len(text) - limit} more characters)"
    return text[: max(limit - len(note), 0)] + note


class NodeLog:
    """A node's log: bounded lines, messages keyed for once-only or throttled logging, counted rejections.

    Parameters
    ----------
    node : rclpy.node.Node or logger
        The node (its ``get_logger()`` is used) or an rclpy logger (anything with ``debug``, ``info``,
        ``warning`` and ``error`` taking one string).
    rejections : Counter of str, optional
        Where rejections are counted, per reason (default: a counter of this log's own, :attr:`rejections`).
    now : callable, optional
        Monotonic clock [s] of the throttling (default :func:`time.monotonic`).

    Examples
    --------
    >>> class Lines:
    ...     def __init__(self): self.lines = []
    ...     def debug(self, s): self.lines.append(("debug", s))
    ...     def info(self, s): self.lines.append(("info", s))
    ...     def warning(self, s): self.lines.append(("warning", s))
    ...     def error(self, s): self.lines.append(("error", s))
    >>> out, t = Lines(), [0.0]
    >>> log = NodeLog(out, now=lambda: t[0])
    >>> [log.warning("publish failed", key="pub") for _ in range(3)]
    [True, False, False]
    >>> [log.warning(f"late {k}", key="late", every=1.0) for k in range(3)]
    [True, False, False]
    >>> t[0] = 1.5
    >>> log.warning("late 3", key="late", every=1.0)
    True
    >>> out.lines[-1]
    ('warning', 'late 3 (2 similar messages suppressed)')
    >>> log.reject("busy", "goal refused: busy"); log.reject("busy", "goal refused: busy")
    >>> log.rejection_values()
    {'rejected': 2, 'rejected.busy': 2}
    >>> [line for line in out.lines if "busy" in line[1]]
    [('warning', 'goal refused: busy (reason busy: logged once, counted in /diagnostics as rejected.busy)')]
    """

    def __init__(self, node: Any, rejections: Counter[str] | None = None,
                 now: Callable[[], float] = time.monotonic) -> None:
        get = getattr(node, "get_logger", None)
        self._logger = get() if get is not None else node
        self.rejections: Counter[str] = rejections if rejections is not None else Counter()
        self._now = now
        self._lock = threading.Lock()
        self._last: dict[str, float] = {}  # key -> when its message was last logged [s]
        self._suppressed: Counter[str] = Counter()  # key -> messages not logged since

    # ------------------------------------------------------------------ severities

    def debug(self, text: str, key: str | None = None, every: float = math.inf) -> bool:
        """Log ``text`` at debug level (see :meth:`warning` for ``key`` and ``every``)."""
        return self._log("debug", text, key, every)

    def info(self, text: str, key: str | None = None, every: float = math.inf) -> bool:
        """Log ``text`` at info level (see :meth:`warning` for ``key`` and ``every``)."""
        return self._log("info", text, key, every)

    def warning(self, text: str, key: str | None = None, every: float = math.inf) -> bool:
        """Log ``text`` as a warning.

        Parameters
        ----------
        text : str
            The line (cut to :data:`LOG_LINE_LIMIT` characters).
        key : str, optional
            The message's name: lines with one key are logged at most once per ``every`` seconds (default:
            once until :meth:`rearm`). None: always logged.
        every : float
            Least time between two lines of one key [s] (``math.inf``: once); a line after suppressed ones
            says how many were suppressed.

        Returns
        -------
        bool
            Whether the line was logged.
        """
        return self._log("warning", text, key, every)

    def error(self, text: str, key: str | None = None, every: float = math.inf) -> bool:
        """Log ``text`` as an error (see :meth:`warning` for ``key`` and ``every``)."""
        return self._log("error", text, key, every)

    def exception(self, text: str, key: str | None = None) -> bool:
        """Log ``text`` as an error with the traceback of the exception being handled, the traceback whole
        (it is there to find a defect; the line limit does not apply to it)."""
        if not self._admit(key, math.inf):
            return False
        self._emit("error", f"{bounded(text)}\n{traceback.format_exc()}")
        return True

    def rearm(self, key: str) -> None:
        """Let the next message of ``key`` be logged (a condition that ended: its return is news again)."""
        with self._lock:
            self._last.pop(key, None)
            self._suppressed.pop(key, None)

    # ------------------------------------------------------------------ rejections

    def reject(self, reason: str, text: str, count: bool = True) -> None:
        """An input refused for ``reason``: counted (unless ``count`` is false: counted elsewhere already, in
        the counter given as ``rejections``), logged as a warning the first time of each reason."""
        if count:
            with self._lock:
                self.rejections[reason] += 1
        self._log("warning", f"{text} (reason {reason}: logged once, counted in /diagnostics as rejected.{reason})",
                  f"rejected.{reason}", math.inf)

    @property
    def rejected_total(self) -> int:
        """Rejections of every reason."""
        return sum(self.rejections.values())

    def rejection_values(self, prefix: str = "rejected") -> dict[str, int]:
        """The ``/diagnostics`` key-values of the rejections: ``<prefix>`` (all) and ``<prefix>.<reason>``."""
        counts = dict(self.rejections)  # a copy: another thread may count meanwhile
        return {prefix: sum(counts.values()), **{f"{prefix}.{k}": v for k, v in sorted(counts.items())}}

    # ------------------------------------------------------------------ internals

    def _admit(self, key: str | None, every: float) -> bool:
        if key is None:
            return True
        now = self._now()
        with self._lock:
            last = self._last.get(key)
            if last is not None and (math.isinf(every) or now - last < every):
                self._suppressed[key] += 1
                return False
            self._last[key] = now
            return True

    def _log(self, level: str, text: str, key: str | None, every: float) -> bool:
        if not self._admit(key, every):
            return False
        line = bounded(text)
        if key is not None:
            with self._lock:
                n = self._suppressed.pop(key, 0)
            if n:
                line = f"{line} ({n} similar message{'s' if n > 1 else ''} suppressed)"
        self._emit(level, line)
        return True

    def _emit(self, level: str, line: str) -> None:
        # one call site per severity: rclpy's logger refuses another severity from the same line
        log = self._logger
        if level == "error":
            log.error(line)
        elif level == "warning":
            log.warning(line)
        elif level == "info":
            log.info(line)
        else:
            log.debug(line)
