"""Wheel-load sources told apart by publisher: one stream per topic, a second publisher refused (issue 26.2).

Two vehicles publishing on one ``wheel_loads`` topic on one clock look like
one stream to the stamp rules (their stamps interleave, their wheel ids are the
same): the model took both (800/800 accepted, answers off by ~100 % of the peak
deflection). rclpy hands a subscription's messages to Python without the
writer's identity, so the track node takes them itself:

- :class:`GidSubscription`: the raw ``wheel_loads`` subscription, created by
  rclpy as usual (QoS overrides, events) but hidden from the executor; its
  messages are taken with ``rcl_take_serialized_message`` (through ctypes),
  whose ``rmw_message_info_t`` carries the publisher's GID. The middleware's
  "new message" callback is libc's ``eventfd_write`` (C, no Python: the
  middleware calls it holding its reader's lock, and a Python callback there
  would wait for the GIL while the executor thread, holding the GIL, waits in
  rclpy for that lock: a deadlock, seen in the soak); a thread of the node
  waits on that eventfd and hands the executor a task (``create_task``, thread
  safe; one at a time) that takes what has arrived (rclpy's EventsExecutor
  serves no guard condition).
- :class:`Sources`: the first publisher heard is the stream's source; a
  message of any other publisher is refused (cause ``second_source``,
  counted, logged once); when the source leaves the graph, or has sent
  nothing for :data:`QUIET_S` (by the middleware's reception times), the next
  publisher heard takes over (a new stream: the model's state restarts).

A source that dies without a goodbye (kill -9) stays on the graph until its
lease runs out (Cyclone DDS: 10 s, Fast DDS: 20 s by default); a client
restarted within it has a new GID. Without the quiet rule it was refused for
the whole lease (every message of a restarted Cyclone client, lease 120 s);
with it, it is served once the dead source has been quiet for
:data:`QUIET_S`. Two live vehicles on one topic are still told apart: each
sends every few milliseconds, so the source is never quiet that long.
"""

from __future__ import annotations

import ctypes
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["GID_BYTES", "QUIET_S", "GidSubscription", "Sources", "gid_text"]

#: Bytes of an rmw GID (``RMW_GID_STORAGE_SIZE`` of ROS 2 Jazzy).
GID_BYTES = 16
#: A source that has sent nothing for this long [s] (reception times) yields to the next publisher heard: shorter
#: than the DDS leases (10-20 s) that keep a dead publisher on the graph, longer than the pauses of a live 1-kHz
#: publisher in the tests. A live source whose messages reach the node more than this late while another
#: publisher's keep arriving (a machine stalled for seconds) loses the stream to it: counted in
#: ``source_quiet_takeovers``, its own messages then refused as ``second_source``.
QUIET_S = 3.0
#: ``RCL_RET_OK`` and ``RCL_RET_SUBSCRIPTION_TAKE_FAILED`` (nothing to take).
_RCL_OK, _RCL_TAKE_FAILED = 0, 401


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _Bytes(ctypes.Structure):  # rcutils_uint8_array_t (rcl_serialized_message_t)
    _fields_ = [("buffer", ctypes.POINTER(ctypes.c_uint8)), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _Gid(ctypes.Structure):  # rmw_gid_t
    _fields_ = [("implementation_identifier", ctypes.c_char_p), ("data", ctypes.c_uint8 * GID_BYTES)]


class _MessageInfo(ctypes.Structure):  # rmw_message_info_t
    _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                ("publication_sequence_number", ctypes.c_uint64), ("reception_sequence_number", ctypes.c_uint64),
                ("publisher_gid", _Gid), ("from_intra_process", ctypes.c_bool)]


_EVENT_CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_size_t)  # rcl_event_callback_t


def _library(name: str) -> ctypes.CDLL:
    """A shared library of ROS already loaded by rclpy (its path from this process's memory map)."""
    with open("/proc/self/maps", encoding="utf-8") as maps:
        for line in maps:
            path = line.split()[-1] if line.strip() else ""
            if path.rsplit("/", 1)[-1] == name:
                return ctypes.CDLL(path)
    return ctypes.CDLL(name)


_LIBS: dict[str, Any] = {}


def _rcl() -> tuple[Any, Any]:
    if not _LIBS:
        rcl, rcutils = _library("librcl.so"), _library("librcutils.so")
        rcutils.rcutils_get_default_allocator.restype = _Allocator
        rcutils.rcutils_get_default_allocator.argtypes = []
        rcutils.rcutils_uint8_array_init.argtypes = [ctypes.POINTER(_Bytes), ctypes.c_size_t,
                                                      ctypes.POINTER(_Allocator)]
        rcutils.rcutils_uint8_array_init.restype = ctypes.c_int
        rcutils.rcutils_uint8_array_fini.argtypes = [ctypes.POINTER(_Bytes)]
        rcutils.rcutils_uint8_array_fini.restype = ctypes.c_int
        rcl.rcl_take_serialized_message.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Bytes),
                                                    ctypes.POINTER(_MessageInfo), ctypes.c_void_p]
        rcl.rcl_take_serialized_message.restype = ctypes.c_int
        rcl.rcl_subscription_set_on_new_message_callback.argtypes = [ctypes.c_void_p, _EVENT_CALLBACK,
                                                                     ctypes.c_void_p]
        rcl.rcl_subscription_set_on_new_message_callback.restype = ctypes.c_int
        _LIBS.update(rcl=rcl, rcutils=rcutils)
    return _LIBS["rcl"], _LIBS["rcutils"]


def gid_text(gid: bytes) -> str:
    """A GID as short hex (the last 8 bytes: Fast DDS puts the host and process prefix first)."""
    return gid[-8:].hex()


class GidSubscription:
    """A raw subscription taken with the publisher's GID, outside the executor (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The node that created ``sub``.
    sub : rclpy.subscription.Subscription
        A raw subscription just created by ``node`` (its callback is never called: the executor never sees it).
    on_ready : callable
        Called on the executor thread when messages have arrived (take them with :meth:`take`). The owner also
        calls it now and then (a message that arrived before the node had an executor rang no one).
    doorbell : bool
        True: a thread waits on the arrival eventfd and hands the executor a task. False: no thread; the owner's
        loop waits on :meth:`fileno` itself (a wait-set loop, :func:`clm_ros.node_main.run_node`) and calls
        :meth:`serve_arrivals` when it is readable.
    """

    def __init__(self, node: Any, sub: Any, on_ready: Callable[[], None], doorbell: bool = True) -> None:
        self.node, self.sub = node, sub
        node._subscriptions.remove(sub)  # hidden from the executor: only this object takes its messages
        self._rcl, self._rcutils = _rcl()
        self._buf = _Bytes()
        alloc = self._rcutils.rcutils_get_default_allocator()
        if self._rcutils.rcutils_uint8_array_init(ctypes.byref(self._buf), 4096, ctypes.byref(alloc)) != _RCL_OK:
            raise MemoryError("cannot allocate the wheel-load buffer")
        self._info = _MessageInfo()
        self._on_ready = on_ready
        self._pending = False
        self.closed = False
        # on arrival the middleware's thread calls eventfd_write(fd, n) (user_data = the fd): C only, no GIL
        self._efd = os.eventfd(0, os.EFD_CLOEXEC if doorbell else os.EFD_CLOEXEC | os.EFD_NONBLOCK)
        libc = ctypes.CDLL(None)
        address = ctypes.cast(libc.eventfd_write, ctypes.c_void_p).value
        if address is None:
            raise OSError("libc has no eventfd_write")
        self._callback = _EVENT_CALLBACK(address)
        self._thread: threading.Thread | None = None
        if doorbell:
            self._thread = threading.Thread(target=self._doorbell, name="clm_wheel_loads_doorbell", daemon=True)
            self._thread.start()
        self._pointer = ctypes.c_void_p(sub.handle.pointer)
        if self._rcl.rcl_subscription_set_on_new_message_callback(self._pointer, self._callback,
                                                                  ctypes.c_void_p(self._efd)) != _RCL_OK:
            raise RuntimeError("rcl_subscription_set_on_new_message_callback failed")

    def _doorbell(self) -> None:
        """Thread: wait on the eventfd (the GIL released), then hand the executor a task; until destroyed."""
        while True:
            try:
                os.eventfd_read(self._efd)
            except OSError:
                return
            if self.closed:
                return
            self._ring(None, 0)

    def _ring(self, _user: Any, _count: int) -> None:
        executor = self.node.executor
        if self._pending or executor is None or self.closed:
            return
        self._pending = True
        executor.create_task(self._serve)

    def _serve(self) -> None:
        self._pending = False  # first: a message arriving from now on rings again
        if not self.closed:
            self._on_ready()

    def fileno(self) -> int:
        """The arrival eventfd (readable when messages have arrived), for a loop that waits on it itself."""
        return self._efd

    def serve_arrivals(self) -> None:
        """Without a doorbell thread: reset the arrival eventfd and take what has arrived (``on_ready``)."""
        try:
            os.eventfd_read(self._efd)
        except BlockingIOError:
            pass
        if not self.closed:
            self._on_ready()

    @property
    def topic_name(self) -> str:
        return str(self.sub.topic_name)

    def get_publisher_count(self) -> int:
        return int(self.sub.get_publisher_count())

    def take(self) -> tuple[bytes, bytes, int] | None:
        """The next message (serialized bytes), its publisher's GID and its reception time (ns since the epoch,
        the middleware's; 0 where it gives none); None when nothing is waiting."""
        if self.closed:
            return None
        buf, info = self._buf, self._info
        ret = self._rcl.rcl_take_serialized_message(self._pointer, ctypes.byref(buf), ctypes.byref(info), None)
        if ret == _RCL_TAKE_FAILED:
            return None
        if ret != _RCL_OK:
            raise RuntimeError(f"rcl_take_serialized_message failed ({ret})")
        return (ctypes.string_at(buf.buffer, buf.buffer_length), bytes(info.publisher_gid.data),
                int(info.received_timestamp))

    def destroy(self) -> None:
        """Stop the arrival callback, destroy the subscription (through the node) and free the buffer."""
        if self.closed:
            return
        self.closed = True
        self._rcl.rcl_subscription_set_on_new_message_callback(self._pointer, _EVENT_CALLBACK(), None)
        if self._thread is not None:
            os.eventfd_write(self._efd, 1)  # the doorbell thread sees closed and ends
            self._thread.join(2.0)
        os.close(self._efd)
        self.node._subscriptions.append(self.sub)  # back in the node's list, destroyed the node's way
        self.node.destroy_subscription(self.sub)
        self._rcutils.rcutils_uint8_array_fini(ctypes.byref(self._buf))


class Sources:
    """Which publisher of a topic is the stream's source (the first heard); the others are refused.

    Parameters
    ----------
    quiet_s : float
        A source that has sent nothing for this long [s] yields to the next publisher heard (:data:`QUIET_S`).

    Attributes
    ----------
    source : bytes or None
        The GID of the stream's source (None until the first message, and after it left the graph).
    refused : Counter
        Messages refused per publisher GID.
    heard : set of bytes
        Every publisher heard.
    takeovers : int
        Sources that took over from a previous one (it left the graph or went quiet).
    quiet_takeovers : int
        Of ``takeovers``, those from a source that went quiet (still on the graph).
    fresh : bool
        Set when a publisher took over from a quiet source: a new stream begins with the message just admitted
        (the owner restarts the state and clears the flag; after a source left the graph the owner knows it from
        :meth:`graph`).
    """

    def __init__(self, quiet_s: float = QUIET_S) -> None:
        if not quiet_s > 0:
            raise ValueError(f"Sources: quiet_s must be > 0 s, got {quiet_s!r}")
        self.quiet_ns = int(quiet_s * 1e9)
        self.source: bytes | None = None
        self.refused: Counter[bytes] = Counter()
        self.heard: set[bytes] = set()
        self.takeovers = 0
        self.quiet_takeovers = 0
        self.fresh = False
        self._last_ns = 0  # reception time of the source's last message [ns]
        self._listed = False  # the source has been seen on the graph

    def admit(self, gid: bytes, received_ns: int = 0) -> bool:
        """Whether a message of publisher ``gid`` belongs to the stream (the first publisher heard becomes it).

        ``received_ns``: the message's reception time [ns since the epoch] (the middleware's; 0: now). A
        message of another publisher arriving more than ``quiet_s`` after the source's last one takes over."""
        now = received_ns if received_ns > 0 else time.time_ns()
        if self.source is not None and gid != self.source and now - self._last_ns > self.quiet_ns:
            self.source, self._listed, self.fresh = None, False, True  # the source went quiet: a new stream
            self.quiet_takeovers += 1
        if self.source is None:
            self.source, self._listed = gid, False
            self.takeovers += int(bool(self.heard))
        self.heard.add(gid)
        if gid == self.source:
            self._last_ns = max(self._last_ns, now)
            return True
        self.refused[gid] += 1
        return False

    def graph(self, publisher_gids: Iterable[Any]) -> bool:
        """The publishers now on the graph; True when the source has left (the next publisher heard takes over).

        The source must have been seen on the graph first: the graph learns of a publisher later than its
        first messages may arrive, and a source not listed yet has not left."""
        present = {bytes(list(g)[:GID_BYTES]) for g in publisher_gids}
        if self.source is None:
            return False
        if self.source in present:
            self._listed = True
            return False
        if self._listed:
            self.source, self._listed = None, False
            return True
        return False

    def values(self) -> dict[str, Any]:
        """Diagnostics key-values: the source, the publishers heard, the messages refused, the takeovers."""
        return {
            "wheel_load_source": gid_text(self.source) if self.source is not None else "none",
            "wheel_load_sources_heard": len(self.heard),
            "second_source_refused": sum(self.refused.values()),
            "source_takeovers": self.takeovers,
            "source_quiet_takeovers": self.quiet_takeovers,
        }
