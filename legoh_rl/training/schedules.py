"""Schedules of env settings over a run's env steps (frames)."""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["feedforward_gain", "check_anneal"]


def check_anneal(anneal: Sequence | None, name: str = "feedforward_anneal") -> tuple[int, int] | None:
    """``(start, end)`` frames of a linear anneal, or ``None`` (no anneal).

    Raises:
        ValueError: not two non-negative integers with ``start < end`` (names ``name`` and the value).
    """
    if anneal is None:
        return None
    try:
        start, end = (int(v) for v in anneal)
        ok = all(float(v) == int(v) for v in anneal)
    except (TypeError, ValueError):
        ok = False
    if not ok or not 0 <= start < end:
        raise ValueError(f"{name} must be [start_frames, end_frames] with 0 <= start < end, got {anneal!r}")
    return start, end


def feedforward_gain(gain: float, frames: int, anneal: Sequence | None) -> float:
    """The gait feedforward gain after ``frames`` env steps of a run.

    ``gain`` until ``start`` frames, then linearly down to 0 at ``end`` frames, 0 after; without
    an anneal always ``gain``. Example: gain 1, anneal (100, 300): 1 at 100, 0.5 at 200, 0 at 300.
    """
    window = check_anneal(anneal)
    if window is None:
        return float(gain)
    start, end = window
    left = min(max((end - frames) / (end - start), 0.0), 1.0)
    return float(gain) * left
