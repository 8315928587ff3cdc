"""The paper's six hiking metrics, accumulated per world and emitted when an episode ends.

Definitions (docs/metrics.md has the reasoning):

* **Success** (SR, %): the episode ended with the robot within the goal radius of P_B
  (0.89 m in evaluation, 0.5 m in training).
* **Trail Completion** (TC, %): share of the trail's expert navigation goals the robot passed
  (came within the goal-reach radius of, in order) — the portion of the trail *route* it
  followed. A robot that finds its own way around obstacles can succeed with a low TC, which
  is what the paper's Forest figures show.
* **Traverse Rate** (TR, %): 100 x (1 - d_final / L), d_final the robot's final distance to P_B,
  L the straight-line trail length |P_B - P_A|; 100 on success, floored at 0.
* **MEV** (%): share of foot-contact samples (one per foot per control step in contact) that
  lie on an edge cell of the terrain.
* **TTF** (s): time to fall — the episode length if it ended by a fall; otherwise the episode
  length (the robot did not fall while observed).
* **Time-to-Reach** (T2R, s): episode length of successful episodes; NaN otherwise (averaged
  over successful episodes only).
"""

from __future__ import annotations

import numpy as np
import torch

from legoh_rl.envs.array_api import namespace_of

__all__ = ["METRIC_NAMES", "EpisodeMetrics"]

METRIC_NAMES = ("success", "trail_completion", "traverse_rate", "mev", "ttf", "time_to_reach")


class EpisodeMetrics:
    """Per-world accumulators for N worlds: numpy arrays, or torch tensors on ``device`` (a
    device-resident step's, docs/gpu_physics.md); the inputs of each method are of the same kind.

    Args:
        num_worlds: N.
        device: ``None`` for numpy (float64) accumulators; a torch device for tensors (float32).
    """

    def __init__(self, num_worlds: int, device: torch.device | str | None = None) -> None:
        n = num_worlds
        if device is None:
            self.contact_samples = np.zeros(n)
            self.edge_samples = np.zeros(n)
            self.goals_passed = np.zeros(n, dtype=np.int64)
        else:
            self.contact_samples = torch.zeros(n, device=device)
            self.edge_samples = torch.zeros(n, device=device)
            self.goals_passed = torch.zeros(n, dtype=torch.int64, device=device)

    def reset(self, ids: np.ndarray) -> None:
        """Start new episodes in worlds ``ids``."""
        self.contact_samples[ids] = 0.0
        self.edge_samples[ids] = 0.0
        self.goals_passed[ids] = 0

    def record_step(self, foot_contact: np.ndarray, foot_on_edge: np.ndarray) -> None:
        """Accumulate one control step: (N, 2) bool foot contacts, (N, 2) bool contact on edges."""
        xp = namespace_of(foot_contact)
        self.contact_samples += xp.sum(xp.astype(foot_contact, self.contact_samples.dtype), axis=1)
        self.edge_samples += xp.sum(xp.astype(foot_contact & foot_on_edge, self.edge_samples.dtype), axis=1)

    def finish(
        self,
        success: np.ndarray,
        episode_time: np.ndarray,
        final_goal_dist: np.ndarray,
        trail_length: np.ndarray,
        num_goals: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """The six metrics of episodes ending now, all (N,) floats (meaningful where done): float64
        arrays, or float32 tensors on the accumulators' device.

        Args:
            success: (N,) bool, reached P_B.
            episode_time: (N,) s.
            final_goal_dist: (N,) final distance to P_B, m.
            trail_length: (N,) |P_B - P_A|, m.
            num_goals: (N,) number of expert goals of each world's trail.
        """
        xp = namespace_of(final_goal_dist)
        dtype = self.contact_samples.dtype
        tr = xp.where(success, 100.0, 100.0 * xp.clip(1.0 - final_goal_dist / xp.maximum(trail_length, 1e-6), 0.0, 1.0))
        return {
            "success": 100.0 * xp.astype(success, dtype),
            "trail_completion": 100.0 * xp.astype(self.goals_passed, dtype) / xp.astype(xp.maximum(num_goals, 1), dtype),
            "traverse_rate": tr,
            "mev": 100.0 * self.edge_samples / xp.maximum(self.contact_samples, 1.0),
            "ttf": xp.astype(episode_time, dtype),
            "time_to_reach": xp.where(success, xp.astype(episode_time, dtype), float("nan")),
        }
