"""Schedules of env settings over a run's env steps (frames): the gait feedforward anneal.

A run's gait feedforward schedule is a :class:`FeedforwardSchedule`: a gain held until ``start``
frames, then linearly down to 0 at ``end`` (no window: the gain stays). The oracle recipe takes it
from its config (``env.gait_feedforward``, ``feedforward_anneal: [start, end]``) or, with
``feedforward_anneal: inherit``, from the checkpoint it starts from: a stage started with
``checkpoint.init`` (networks only, its frame count from 0) goes on along the same line as its
init, from the gain the init had at its last frame (:func:`inherited_schedule`). Each checkpoint
records the schedule it followed in its own frames (``state["feedforward_schedule"]``,
:meth:`FeedforwardSchedule.record`), which a resume and a later stage read
(:func:`recorded_schedule`); a checkpoint written before that record existed is read from the
config it recorded.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ["INHERIT", "RECORD_KEY", "FeedforwardSchedule", "check_anneal", "feedforward_gain",
           "inherited_schedule", "recorded_schedule"]

#: ``feedforward_anneal``'s value for "go on with checkpoint.init's schedule"
INHERIT = "inherit"
#: the checkpoint entry that holds the schedule a run followed (:meth:`FeedforwardSchedule.record`)
RECORD_KEY = "feedforward_schedule"


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


@dataclass(frozen=True)
class FeedforwardSchedule:
    """The gait feedforward gain of one run over its own frames.

    Attributes:
        gain: the gain until ``anneal[0]`` frames (>= 0).
        anneal: ``(start, end)`` run frames over which the gain goes linearly to 0, or None (it
            stays ``gain``).
    """

    gain: float
    anneal: tuple[int, int] | None = None

    def __post_init__(self):
        if isinstance(self.gain, bool) or not isinstance(self.gain, int | float) or not math.isfinite(self.gain) \
                or self.gain < 0:
            raise ValueError(f"a gait feedforward schedule's gain must be a number >= 0, got {self.gain!r}")
        object.__setattr__(self, "gain", float(self.gain))
        object.__setattr__(self, "anneal", check_anneal(self.anneal))

    def at(self, frames: int) -> float:
        """The gain after ``frames`` run frames (:func:`feedforward_gain`)."""
        return feedforward_gain(self.gain, frames, self.anneal)

    def after(self, frames: int) -> FeedforwardSchedule:
        """The same line in the frames of a run that starts where this one stood at ``frames``.

        Before the window: the window moves ``frames`` earlier. Inside it: the gain at ``frames``,
        annealed over ``[0, end - frames]`` (the same slope). After it (or no window): a constant
        gain, 0 or ``gain``. Example: gain 1 over (10M, 50M), after 13,111,296 frames: gain
        0.9222176 over (0, 36,888,704).
        """
        if self.anneal is None:
            return self
        start, end = self.anneal
        if frames >= end:
            return FeedforwardSchedule(0.0)
        if frames <= start:
            return FeedforwardSchedule(self.gain, (start - frames, end - frames))
        return FeedforwardSchedule(self.at(frames), (0, end - frames))

    def record(self) -> dict:
        """``{"gain": float, "anneal": [start, end] | None}``: the checkpoint's entry for it."""
        return {"gain": self.gain, "anneal": None if self.anneal is None else list(self.anneal)}

    def describe(self) -> str:
        """One line for the logs: ``gain 0.9222176 to 0 over run frames [0, 36888704]`` or ``gain 1 (constant)``."""
        if self.anneal is None:
            return f"gain {self.gain:.8g} (constant)"
        return f"gain {self.gain:.8g} to 0 over run frames [{self.anneal[0]}, {self.anneal[1]}]"


def recorded_schedule(state: Mapping, path: str | os.PathLike) -> FeedforwardSchedule:
    """The gait feedforward schedule checkpoint ``state`` (read from ``path``) followed, in its
    run's frames: its ``feedforward_schedule`` entry, or, for a checkpoint written before that
    entry, the ``env.gait_feedforward`` and ``feedforward_anneal`` of the config it recorded.

    Raises:
        ValueError: the checkpoint records neither (a policy file without its config), its config
            asked for ``inherit`` without the entry, or the record is not a schedule; each names
            ``path``.
    """
    record = state.get(RECORD_KEY)
    if record is not None:
        try:
            return FeedforwardSchedule(record["gain"], record.get("anneal"))
        except (KeyError, TypeError, AttributeError, ValueError) as err:
            raise ValueError(f"{path}: its {RECORD_KEY} entry {record!r} is not a schedule ({err})") from None
    config = state.get("config")
    if not isinstance(config, Mapping) or not isinstance(config.get("env"), Mapping):
        raise ValueError(f"{path} records no gait feedforward schedule (no {RECORD_KEY} entry and no recorded "
                         f"config): feedforward_anneal=inherit needs a run's checkpoint (last.pt) or its export")
    anneal = config.get("feedforward_anneal")
    if anneal == INHERIT:
        raise ValueError(f"{path} records feedforward_anneal=inherit but not the schedule it followed "
                         f"(no {RECORD_KEY} entry)")
    try:
        return FeedforwardSchedule(config["env"].get("gait_feedforward", 0.0), anneal)
    except ValueError as err:
        raise ValueError(f"{path}: its recorded config holds no gait feedforward schedule ({err})") from None


def inherited_schedule(state: Mapping, path: str | os.PathLike) -> FeedforwardSchedule:
    """The schedule of a run started from checkpoint ``state`` (``checkpoint.init``, read from
    ``path``) that goes on with it: :func:`recorded_schedule` moved on by the checkpoint's
    ``frames`` (:meth:`FeedforwardSchedule.after`).

    Raises:
        ValueError: the checkpoint records no schedule or no frame count (each names ``path``).
    """
    schedule = recorded_schedule(state, path)
    frames = state.get("frames")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 0:
        raise ValueError(f"{path} records no frame count (frames={frames!r}): feedforward_anneal=inherit "
                         "cannot tell where its schedule stood")
    return schedule.after(frames)
