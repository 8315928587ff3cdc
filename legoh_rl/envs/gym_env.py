"""Single-world Gymnasium view of :class:`~legoh_rl.envs.hiking.HikingEnv`.

Registered ids: ``LegoH/Hike-H1-v0`` and ``LegoH/Hike-G1-v0`` (oracle observations) and
``LegoH/HikeDepth-H1-v0`` / ``LegoH/HikeDepth-G1-v0`` (with the depth camera)::

    import gymnasium, legoh_rl.envs
    env = gymnasium.make("LegoH/Hike-H1-v0")
    obs, info = env.reset(seed=0)

Observations are a ``Dict`` of float32 boxes with the env's keys; ``info`` carries the
weighted reward terms and, when an episode ends, its metrics. For training, use the batched
TorchRL env: this wrapper exists for tooling that speaks Gymnasium.
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import torch

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv

__all__ = ["HikingGymEnv"]

_OBS_KEYS = ("proprio", "goal_gps", "waypoint_gps", "scandots", "privileged", "expert_goals", "depth")


class HikingGymEnv(gym.Env):
    """One world of the hiking env behind the Gymnasium API.

    Args:
        robot: ``"h1"`` or ``"g1"``.
        mode: ``"oracle"``, ``"student"`` or ``"eval"``.
        trails: optional terrain (see :class:`~legoh_rl.envs.hiking.TrailSource`).
        **cfg: other :class:`~legoh_rl.envs.config.HikingEnvConfig` fields.
    """

    metadata = {"render_modes": []}

    def __init__(self, robot: str = "h1", mode: str = "oracle", trails=None, **cfg) -> None:
        config = replace(HikingEnvConfig(), robot=robot, mode=mode, num_envs=1, **cfg)
        self.env = HikingEnv(config, trails=trails)
        spec = self.env.observation_spec
        spaces = {}
        for key in _OBS_KEYS:
            if key not in spec.keys():
                continue
            s = spec[key]
            low = s.space.low[0].cpu().numpy() if hasattr(s, "space") and hasattr(s.space, "low") else -np.inf
            high = s.space.high[0].cpu().numpy() if hasattr(s, "space") and hasattr(s.space, "high") else np.inf
            spaces[key] = gym.spaces.Box(low=low, high=high, shape=tuple(s.shape[1:]), dtype=np.float32)
        self.observation_space = gym.spaces.Dict(spaces)
        clip = config.action_clip
        self.action_space = gym.spaces.Box(-clip, clip, shape=(self.env.A,), dtype=np.float32)

    def _obs(self, td) -> dict:
        return {k: td[k][0].cpu().numpy().astype(np.float32) for k in self.observation_space.spaces}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(seed)
        td = self.env.reset()
        return self._obs(td), {}

    def step(self, action):
        action = np.asarray(action, dtype=np.float32).reshape(1, -1)
        nxt = self.env.step(_as_td(self.env, action))["next"]
        reward = float(nxt["reward"][0, 0])
        terminated = bool(nxt["terminated"][0, 0])
        truncated = bool(nxt["truncated"][0, 0])
        info = {"reward_terms": {k: float(v[0, 0]) for k, v in nxt["reward_terms"].items()}}
        if terminated or truncated:
            info["episode"] = {k: float(v[0, 0]) for k, v in nxt["episode"].items()}
        return self._obs(nxt), reward, terminated, truncated, info


def _as_td(env: HikingEnv, action: np.ndarray):
    from tensordict import TensorDict

    return TensorDict({"action": torch.as_tensor(action, device=env.device)}, batch_size=env.batch_size, device=env.device)
