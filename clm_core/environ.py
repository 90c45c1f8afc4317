"""Variables of this process's environment set for a while, then put back as they were.

One home for the save/restore of ``os.environ`` entries: the study engine puts
back what a dask nanny's pre-spawn environment overwrote
(:mod:`clm_core.studies.engine`), the ROS run harness sets its participant's
Fast DDS variables around the participant's creation only
(``clm_ros.harness``).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Mapping

__all__ = ["Saved", "environment", "restore", "save"]

#: Variables and their values as found (None: not set).
Saved = dict[str, str | None]


def save(names: Iterable[str]) -> Saved:
    """The current value of each variable in ``names`` (None where it is not set)."""
    return {name: os.environ.get(name) for name in names}


def restore(saved: Saved) -> None:
    """Put every variable of ``saved`` back as it was: its value, or unset."""
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


@contextlib.contextmanager
def environment(values: Mapping[str, str]) -> Iterator[None]:
    """Set ``values`` in this process's environment for the block, then put back what was there."""
    saved = save(values)
    os.environ.update(values)
    try:
        yield
    finally:
        restore(saved)
