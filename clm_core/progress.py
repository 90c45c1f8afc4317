"""Progress of long runs: a bar on a terminal, silence otherwise.

One helper for every long command (``clm simulate``, ``replay``,
``calibrate``, ``soil-calibrate``, ``report``, ``demo``) and for the core
functions they call: :class:`Progress` draws a tqdm bar on stderr when stderr
is a terminal and does nothing otherwise (pipes, log files, CI), so scripted
use stays quiet. tqdm is imported only when a bar is drawn.

A bar may have no known total (``total=None``: a counter); the object is
always truthy, so ``if bar:`` tests can never fail on it (tqdm's own bar
raises ``TypeError: bool() undefined`` without a total).
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any


def terminal() -> bool:
    """True if stderr is a terminal (where progress is shown)."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # replaced or closed stream
        return False


class Progress:
    """A progress bar on stderr when it is a terminal; a no-op otherwise.

    Parameters
    ----------
    total : float, optional
        Amount of work (steps, messages, items); None: unknown (a counter).
    desc : str
        Label, e.g. ``"clm simulate"``.
    unit : str
        Unit of the work (``step``, ``msg``, ``%``).
    enabled : bool, optional
        Force the bar on or off (default: :func:`terminal`).
    """

    def __init__(self, total: float | None, desc: str, unit: str = "it", enabled: bool | None = None) -> None:
        self.enabled = terminal() if enabled is None else bool(enabled)
        self.n: float = 0
        self._bar: Any = None
        if self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True)

    def __bool__(self) -> bool:
        return True

    def update(self, n: float = 1) -> None:
        """Add ``n`` units of work done."""
        self.n += n
        if self._bar is not None:
            self._bar.update(n)

    def update_to(self, done: float) -> None:
        """Set the work done to ``done`` units (ignored if it would go back)."""
        if done > self.n:
            self.update(done - self.n)

    def stage(self, text: str) -> None:
        """Show what is being done (after the bar)."""
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=True)

    def fraction(self, stage: str, frac: float) -> None:
        """Callback form ``(stage, fraction done in [0, 1])`` for a bar of total 100 (``unit='%'``)."""
        self.stage(stage)
        self.update_to(round(100 * min(max(frac, 0.0), 1.0)))

    def close(self) -> None:
        """Draw the bar's final count once (tqdm redraws at most every 0.1 s, so the last updates may not have
        been drawn), then remove it."""
        if self._bar is not None:
            self._bar.refresh()
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
