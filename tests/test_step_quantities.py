"""StepQuantities on hand-made states: the same goal tracking, episode ends and episode scores
from numpy arrays (the host step) and from torch tensors (the device-resident step)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from legoh_rl.envs.metrics import EpisodeMetrics
from legoh_rl.envs.step_quantities import StepQuantities


class _Worlds(StepQuantities):
    """Three worlds on one straight trail from (0, 0) to P_B = (3, 0), expert goals at x = 1, 2."""

    def __init__(self, kind: str) -> None:
        as_ = (lambda a, dt=None: np.asarray(a, dtype=dt)) if kind == "numpy" else (
            lambda a, dt=None: torch.as_tensor(np.asarray(a, dtype=dt)))
        self.cfg = SimpleNamespace(goal_reach_radius=0.3, num_goals=2, fall_roll_pitch=0.8, fall_height_ratio=0.5,
                                   reach_radius=0.5, cmd_speed=0.5, max_episode_s=4.0)
        self.robot = SimpleNamespace(base_height_target=1.0)
        self.dt, self.max_steps = 0.02, 200
        n = 3
        self.world_index = as_(np.arange(n), np.int64)
        self.goal_offsets = as_(np.arange(2), np.int64)
        self.goals = as_(np.tile([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]], (n, 1, 1)))
        self.num_goals = as_([3] * n, np.int64)
        self.goal_idx = as_([0] * n, np.int64)
        self.start = as_(np.zeros((n, 3)))
        self.end = as_(np.tile([3.0, 0, 0], (n, 1)))
        self.tile = as_([0, 1, 1], np.int64)
        self.tile_level, self.tile_category = as_([0, 3], np.int64), as_([2, 4], np.int64)
        self.episode_step = as_([50, 100, 200], np.int64)
        self.metrics = EpisodeMetrics(n, device=None if kind == "numpy" else "cpu")
        self.ended = None

    def _episodes_ended(self, done, progress, expected, success) -> None:
        self.ended = (done, progress, expected, success)


def _np(x) -> np.ndarray:
    return x.numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _pos(w: _Worlds, xy) -> np.ndarray | torch.Tensor:
    pos = np.concatenate([np.asarray(xy, dtype=np.float64), np.ones((len(xy), 1))], axis=1)
    return pos if isinstance(w.goals, np.ndarray) else torch.as_tensor(pos)


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_goals_move_on_when_reached_or_passed_and_only_reaching_counts(kind: str) -> None:
    w = _Worlds(kind)
    # world 0 within 0.3 m of goal 1; world 1 0.6 m past it along the next leg; world 2 short of it
    w._advance_goals(_pos(w, [[0.8, 0.1], [1.6, 0.0], [0.5, 0.0]]))
    assert _np(w.goal_idx).tolist() == [1, 1, 0]
    assert _np(w.metrics.goals_passed).tolist() == [1, 0, 0]
    dirs = _np(w._goal_dirs(_pos(w, [[1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])))
    assert dirs.shape == (3, 2, 2)
    np.testing.assert_allclose(dirs[0], [[np.sqrt(0.5), -np.sqrt(0.5)], [np.sqrt(0.8), -np.sqrt(0.2)]], atol=1e-12)
    np.testing.assert_allclose(dirs[1], [[1.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(dirs[2], [[1.0, 0.0], [1.0, 0.0]])
    # at P_B the goal index stays on the last goal, and the directions to it are clamped there
    for _ in range(3):
        w._advance_goals(_pos(w, [[3.0, 0.0], [3.0, 0.0], [3.0, 0.0]]))
    assert _np(w.goal_idx).tolist() == [2, 2, 2]
    rows = w.world_index[1:2]
    assert _np(w._goal_dirs(_pos(w, [[2.0, 0.0]]), rows)).tolist() == [[[1.0, 0.0], [1.0, 0.0]]]


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_episode_ends_on_hand_made_states(kind: str) -> None:
    w = _Worlds(kind)
    cast = np.asarray if kind == "numpy" else torch.as_tensor
    state = {"roll": cast([0.9, 0.0, 0.0]), "pitch": cast([0.0, 0.0, 0.0]), "base_height": cast([1.0, 1.0, 1.0]),
             "goal_dist": cast([2.0, 0.3, 1.0])}
    fell, success, terminated, truncated, done = (_np(x).tolist() for x in w._episode_ends(state, cast([False] * 3)))
    assert fell == [True, False, False]  # rolled past 0.8 rad
    assert success == [False, True, False]  # within the 0.5 m reach radius
    assert truncated == [False, False, True]  # world 2 is at its 200th step
    assert terminated == [True, True, False] and done == [True, True, True]
    # a diverged world is truncated, neither fallen nor successful, however it lies
    state["base_height"] = cast([0.2, 0.2, 0.2])
    fell, success, _, truncated, _ = (_np(x).tolist() for x in w._episode_ends(state, cast([True, True, False])))
    assert fell == [False, False, True] and success == [False, False, False]
    assert truncated == [True, True, False]


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_finished_episodes_score_and_reach_the_curriculum(kind: str) -> None:
    w = _Worlds(kind)
    cast = np.asarray if kind == "numpy" else torch.as_tensor
    w.metrics.goals_passed[:] = cast(np.array([1, 2, 0]))
    done, success = cast([True, True, False]), cast([False, True, False])
    episode = {k: _np(v) for k, v in w._finish_episodes(done, success, {"goal_dist": cast([1.5, 0.2, 3.0])}).items()}
    np.testing.assert_allclose(episode["success"], [0.0, 100.0, 0.0])
    np.testing.assert_allclose(episode["trail_completion"], [50.0, 100.0, 0.0])  # of the 2 expert goals
    np.testing.assert_allclose(episode["traverse_rate"], [50.0, 100.0, 0.0])  # 1 - 1.5 / 3; 100 on success
    np.testing.assert_allclose(episode["ttf"], [1.0, 2.0, 0.0])  # 50 and 100 steps of 0.02 s; 0 where not done
    assert np.isnan(episode["time_to_reach"][[0, 2]]).all() and episode["time_to_reach"][1] == pytest.approx(2.0)
    assert episode["level"].tolist() == [0, 3, 3] and episode["category"].tolist() == [2, 4, 4]
    ended, progress, expected, succeeded = (_np(x) for x in w.ended)
    assert ended.tolist() == [True, True, False] and succeeded.tolist() == [False, True, False]
    np.testing.assert_allclose(progress, [1.5, 2.8, 0.0])  # trail length minus the final distance, floored at 0
    np.testing.assert_allclose(expected, [2.0, 2.0, 2.0])  # 0.5 m/s x 4 s, shorter than the 3 m trail
    empty = {k: _np(v) for k, v in w._empty_episode().items()}
    assert not empty["success"].any() and np.isnan(empty["time_to_reach"]).all()
