"""Stop a training loop cleanly on SIGINT / SIGTERM.

The first signal only sets :attr:`GracefulStop.signum`; the loop finishes its iteration, writes
its checkpoint and returns, so the checkpoint is the same state a periodic one would be. A second
signal stops at once (``KeyboardInterrupt``), for a run that hangs.
"""

from __future__ import annotations

import signal
import threading

__all__ = ["GracefulStop"]


class GracefulStop:
    """Context manager that turns SIGINT/SIGTERM into a request to stop after this iteration.

    Attributes:
        signum: the signal received (``None`` until one arrives).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum, frame) -> None:
        if self.signum is not None:  # second signal: stop now
            raise KeyboardInterrupt
        self.signum = signum
        print(f"\n{signal.Signals(signum).name}: stopping after this iteration with a checkpoint "
              "(send it again to stop at once)", flush=True)

    def __enter__(self) -> GracefulStop:
        if threading.current_thread() is threading.main_thread():  # handlers only install there
            for s in self.SIGNALS:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()
