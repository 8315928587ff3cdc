"""Run-frame schedules (the gait feedforward anneal) and the per-category / per-level training stats."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from legoh_rl.training.schedules import (
    FeedforwardSchedule,
    check_anneal,
    feedforward_gain,
    inherited_schedule,
    recorded_schedule,
)
from legoh_rl.training.stats import curriculum_stats, split_episode_stats


def test_feedforward_gain_hand_values():
    assert feedforward_gain(1.0, 0, None) == 1.0
    assert feedforward_gain(0.8, 10**9, None) == 0.8
    window = (100, 300)
    assert feedforward_gain(1.0, 0, window) == 1.0
    assert feedforward_gain(1.0, 100, window) == 1.0
    assert feedforward_gain(1.0, 200, window) == pytest.approx(0.5)
    assert feedforward_gain(2.0, 250, window) == pytest.approx(0.5)
    assert feedforward_gain(1.0, 300, window) == 0.0
    assert feedforward_gain(1.0, 10_000, window) == 0.0


@pytest.mark.parametrize("bad", [[300, 100], [5, 5], [-1, 10], [1], [1, 2, 3], ["a", 3], [1.5, 3]])
def test_bad_anneal_windows_refused(bad):
    with pytest.raises(ValueError, match=r"feedforward_anneal must be \[start_frames, end_frames\]"):
        check_anneal(bad)


def _batch(done, category, level, success, completion):
    n = len(done)
    col = lambda v, dt: torch.tensor(v, dtype=dt).reshape(1, n, 1)  # noqa: E731  [1 world, n steps, 1]
    episode = {"category": col(category, torch.int64), "level": col(level, torch.int64),
               "success": col(success, torch.float32), "trail_completion": col(completion, torch.float32)}
    return TensorDict({"next": {"done": col(done, torch.bool), "episode": episode}}, batch_size=[1, n])


def test_split_episode_stats_hand_made_batch():
    # five steps, four episode ends: randommix L0 success, gap L1 fail, gap L1 success, and one
    # not done (ignored whatever its values); ditch never ends
    data = _batch(done=[1, 1, 0, 1, 0], category=[0, 2, 0, 2, 1], level=[0, 1, 0, 1, 3],
                  success=[100, 0, 100, 100, 100], completion=[100, 20, 0, 60, 0])
    out = split_episode_stats(data, ("randommix", "ditch", "gap"))
    assert out["episode/randommix/success"] == 100 and out["episode/randommix/episodes"] == 1
    assert out["episode/gap/success"] == 50 and out["episode/gap/trail_completion"] == 40
    assert out["episode/gap/episodes"] == 2
    assert out["episode/level0/success"] == 100 and out["episode/level1/success"] == 50
    assert "episode/ditch/success" not in out and "episode/level3/success" not in out
    none = _batch(done=[0, 0], category=[0, 0], level=[0, 0], success=[0, 0], completion=[0, 0])
    assert split_episode_stats(none, ("randommix",)) == {}


def test_curriculum_stats_mean_level_per_category():
    levels = np.array([0, 4, 2, 1, 3])
    cats = np.array([0, 0, 1, 1, 1])
    out = curriculum_stats(levels, cats, ("randommix", "ditch", "gap"))
    means = {k: v for k, v in out.items() if "share" not in k}
    assert means == {"curriculum/randommix": 2.0, "curriculum/ditch": 2.0}
    assert [out[f"curriculum/share_level{k}"] for k in range(5)] == [0.2] * 5


# ------------------------------------------------------------------------------- inherited schedules

def test_a_schedule_moved_on_keeps_its_line():
    """after(F): the same gain at every frame of the lineage, counted from F."""
    line = FeedforwardSchedule(1.0, (10_000_000, 50_000_000))
    assert line.after(13_111_296) == FeedforwardSchedule(0.9222176, (0, 36_888_704))
    assert line.after(4_000_000) == FeedforwardSchedule(1.0, (6_000_000, 46_000_000))  # before the window
    assert line.after(10_000_000) == FeedforwardSchedule(1.0, (0, 40_000_000))
    assert line.after(50_000_000) == line.after(60_000_000) == FeedforwardSchedule(0.0)  # annealed away
    assert FeedforwardSchedule(0.7).after(10**9) == FeedforwardSchedule(0.7)  # constant stays
    for frames in (0, 5_000_000, 13_111_296, 30_000_000):
        moved = line.after(frames)
        for later in (0, 1_000_000, 20_000_000, 45_000_000):
            assert moved.at(later) == pytest.approx(line.at(frames + later), abs=1e-12)
    # twice moved is once moved by the sum
    twice = line.after(13_111_296).after(16_558_080)
    assert twice.anneal == line.after(29_669_376).anneal
    assert twice.gain == pytest.approx(line.after(29_669_376).gain, rel=1e-12)


def test_recorded_schedule_reads_the_entry_or_the_recorded_config():
    entry = {"feedforward_schedule": {"gain": 0.5, "anneal": [0, 100]}, "config": {"env": {"gait_feedforward": 9.0}}}
    assert recorded_schedule(entry, "a.pt") == FeedforwardSchedule(0.5, (0, 100))  # the entry wins
    old = {"config": {"env": {"gait_feedforward": 0.922}, "feedforward_anneal": [0, 36_900_000]}, "frames": 16_558_080}
    assert recorded_schedule(old, "b.pt") == FeedforwardSchedule(0.922, (0, 36_900_000))
    assert recorded_schedule({"config": {"env": {"gait_feedforward": 1.0}}}, "c.pt") == FeedforwardSchedule(1.0)
    assert recorded_schedule({"config": {"env": {}}}, "d.pt") == FeedforwardSchedule(0.0)  # before the setting
    assert FeedforwardSchedule(0.5, (0, 100)).record() == {"gain": 0.5, "anneal": [0, 100]}
    assert FeedforwardSchedule(1).record() == {"gain": 1.0, "anneal": None}


def test_the_h1_stages_inherit_from_hand_made_records():
    """Stage 1 (gain 1, anneal [10M, 50M]) ended at 13,111,296 frames; stage 2, started at the
    hand-copied 0.922 over [0, 36.9M], was stopped at 16,558,080."""
    stage1 = {"config": {"env": {"gait_feedforward": 1.0}, "feedforward_anneal": [10_000_000, 50_000_000]},
              "frames": 13_111_296}
    assert inherited_schedule(stage1, "stage1.pt") == FeedforwardSchedule(0.9222176, (0, 36_888_704))
    stage2 = {"config": {"env": {"gait_feedforward": 0.922}, "feedforward_anneal": [0, 36_900_000]},
              "frames": 16_558_080}
    stage3 = inherited_schedule(stage2, "stage2.pt")
    assert stage3 == FeedforwardSchedule(0.5082723642276423, (0, 20_341_920))  # the numbers copied by hand
    # a stage 2 that had inherited its start would have ended elsewhere on the line
    recorded2 = {"feedforward_schedule": {"gain": 0.9222176, "anneal": [0, 36_888_704]}, "frames": 16_558_080}
    assert inherited_schedule(recorded2, "s.pt") == FeedforwardSchedule(0.5082656, (0, 20_330_624))


@pytest.mark.parametrize("state, message", [
    ({"frames": 10}, r"x.pt records no gait feedforward schedule \(no feedforward_schedule entry and no recorded "
                     r"config\)"),
    ({"config": {}, "frames": 10}, r"x.pt records no gait feedforward schedule"),
    ({"config": {"env": {"gait_feedforward": 1.0}, "feedforward_anneal": "inherit"}, "frames": 10},
     r"x.pt records feedforward_anneal=inherit but not the schedule it followed"),
    ({"config": {"env": {"gait_feedforward": 1.0}, "feedforward_anneal": [5, 1]}, "frames": 10},
     r"x.pt: its recorded config holds no gait feedforward schedule \(feedforward_anneal must be"),
    ({"feedforward_schedule": {"anneal": [0, 1]}, "frames": 10}, r"x.pt: its feedforward_schedule entry .* is not a "
                                                                  r"schedule"),
    ({"feedforward_schedule": {"gain": -1.0}, "frames": 10}, r"x.pt: its feedforward_schedule entry .*must be a "
                                                               r"number >= 0, got -1.0"),
    ({"feedforward_schedule": {"gain": 1.0, "anneal": None}}, r"x.pt records no frame count \(frames=None\)"),
])
def test_a_checkpoint_without_a_schedule_or_frames_is_refused_naming_it(state, message):
    with pytest.raises(ValueError, match=message):
        inherited_schedule(state, "x.pt")
