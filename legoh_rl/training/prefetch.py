"""Collecting the next batch in a thread while the update runs (``collector.overlap``).

Two pieces the training loop (:mod:`legoh_rl.training.runner`) uses:

* :class:`Prefetch`: ``next(iterator)`` of a collector in a thread, joined by :meth:`Prefetch.result`
  (which re-raises the thread's error in the caller). MuJoCo's batched step and torch's operators
  release the GIL, so on a 2-core machine the physics of one batch and the update of the other
  share the cores (``docs/scaling.md``, "Collection during the update").
* :func:`thread_local_sampling_mode`: tensordict keeps the sampling mode of probabilistic modules
  (``set_interaction_type``, torchrl's ``set_exploration_type``) in one process-wide variable,
  and every torchrl loss sets it to its deterministic mode for the length of its forward pass.
  With the update in one thread and the collection in another, the collecting actor would then
  take the distribution's mean instead of a sample for whichever steps fell inside a loss pass.
  This swaps that variable for a context variable (one value per thread, as torchrl's own
  recurrent mode is kept), so each thread sees the mode it set.
"""

from __future__ import annotations

import contextvars
import threading
import time
from collections.abc import Iterator

import torch
from tensordict.nn import probabilistic

__all__ = ["Prefetch", "next_batch", "thread_local_sampling_mode"]


def next_batch(iterator: Iterator) -> tuple:
    """``(the iterator's next batch, or None when it is done; the seconds it took)``."""
    start = time.perf_counter()
    try:
        data = next(iterator)
    except StopIteration:
        data = None
    return data, time.perf_counter() - start


class Prefetch:
    """:func:`next_batch` of ``iterator`` in a thread that runs torch on one thread.

    Args:
        iterator: a collector's iterator (nothing else may step its env until :meth:`result`).
    """

    def __init__(self, iterator: Iterator) -> None:
        self._out: dict = {}
        self._thread = threading.Thread(target=self._run, args=(iterator,), name="legoh-collect", daemon=True)
        self._thread.start()

    def _run(self, iterator: Iterator) -> None:
        try:
            torch.set_num_threads(1)
            self._out["batch"] = next_batch(iterator)
        except BaseException as e:  # noqa: BLE001 (re-raised in the caller by result())
            self._out["error"] = e

    def result(self) -> tuple:
        """``(batch or None, its collection seconds)`` once the thread is done.

        Raises:
            whatever the collection raised, in the caller's thread.
        """
        self._thread.join()
        if "error" in self._out:
            raise self._out["error"]
        return self._out["batch"]


class _ThreadMode:
    """tensordict's mode holder (``get_mode`` / ``set_mode``) with one value per thread."""

    def __init__(self, default) -> None:
        self._var = contextvars.ContextVar("legoh_rl_interaction_type", default=default)

    def get_mode(self):
        return self._var.get()

    def set_mode(self, mode) -> None:
        self._var.set(mode)


def thread_local_sampling_mode() -> None:
    """Give every thread its own sampling mode of tensordict's probabilistic modules (idempotent).

    A thread started afterwards begins with the mode in force when this was first called (None,
    outside any ``set_interaction_type`` block: each module's ``default_interaction_type``).

    Raises:
        RuntimeError: this tensordict keeps the mode elsewhere (the swap would do nothing).
    """
    holder = getattr(probabilistic, "_interaction_type", None)
    if isinstance(holder, _ThreadMode):
        return
    if holder is None or not all(hasattr(holder, m) for m in ("get_mode", "set_mode")):
        raise RuntimeError("collector.overlap: tensordict.nn.probabilistic._interaction_type is not the mode holder "
                           "this version of legoh-rl knows; collecting beside the update would sample wrongly")
    probabilistic._interaction_type = _ThreadMode(holder.get_mode())
