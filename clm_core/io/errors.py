"""Exception types of :mod:`clm_core.io`.

Both derive from :class:`clm_core.errors.InputError` (bad run-time input), so
the ``clm`` command prints them as one line and exits with code 2. Every
message says what was wrong, with which value, and where (bag path, topic,
byte offset).
"""

from __future__ import annotations

from clm_core.errors import InputError

__all__ = ["BagError", "MessageError"]


class MessageError(InputError):
    """A message cannot be encoded or decoded.

    Raised by the CDR codec (:mod:`clm_core.io.messages`) for truncated or
    malformed buffers (wrong encapsulation, lengths that do not fit, a
    string without its terminating NUL or not UTF-8, a stamp outside
    ``builtin_interfaces/Time``), by the encoders for arrays of different
    lengths or values outside the field's type, and when the ``clm_msgs``
    definitions cannot be found or parsed.
    """


class BagError(InputError):
    """A bag cannot be read or written as asked.

    Raised for missing, empty, truncated or corrupt bags, message counts that
    disagree with the bag's metadata (missing or damaged chunks), a topic that
    is absent or carries another message type than expected, and an output
    path that exists; by the calibration readers also for messages without the
    expected field, clipped records (flat tops at the sensor limit) and
    inconsistent sampling (jittered or gappy stamps). The message names the
    bag path or the topic and, where it applies, the value, the counts and
    the damaged byte range.
    """
