"""Run-frame schedules (the gait feedforward anneal) and the per-category / per-level training stats."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from legoh_rl.training.schedules import check_anneal, feedforward_gain
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
