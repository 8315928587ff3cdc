"""Single-world Gymnasium view of :class:`~legoh_rl.envs.hiking.HikingEnv`.

Registered ids: ``LegoH/Hike-H1-v0`` and ``LegoH/Hike-G1-v0`` (oracle observations) and
``LegoH/HikeDepth-H1-v0`` / ``LegoH/HikeDepth-G1-v0`` (with the depth camera)::

    import gymnasium, legoh_rl.envs
    env = gymnasium.make("LegoH/Hike-H1-v0")
    obs, info = env.reset(seed=0)

Observations are a ``Dict`` of float32 boxes with the env's keys; ``info`` carries the
weighted reward terms and, when an episode ends, its metrics. For training, use the batched
TorchRL env: this wrapper exists for tooling that speaks Gymnasium.

Rendering: ``gymnasium.make(id, render_mode="rgb_array")`` makes ``env.render()`` return the
robot as a (height, width, 3) uint8 frame (default 240 x 320) from a camera tracking its torso;
``width``, ``height`` and ``camera`` are keyword arguments of ``make`` (see
:meth:`HikingEnv.render <legoh_rl.envs.hiking.HikingEnv.render>`). Gymnasium's wrappers then work
as usual, e.g. ``gymnasium.wrappers.RecordVideo``.
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import torch

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.render import DEFAULT_HEIGHT, DEFAULT_WIDTH

__all__ = ["HikingGymEnv"]

_OBS_KEYS = ("proprio", "goal_gps", "waypoint_gps", "scandots", "privileged", "expert_goals", "depth")


class HikingGymEnv(gym.Env):
    """One world of the hiking env behind the Gymnasium API.

    Args:
        robot: ``"h1"`` or ``"g1"``.
        mode: ``"oracle"``, ``"student"`` or ``"eval"``.
        trails: optional terrain (see :class:`~legoh_rl.envs.hiking.TrailSource`).
        render_mode: ``None`` (no frames) or ``"rgb_array"``: :meth:`render` returns a
            (height, width, 3) uint8 frame.
        width: frame width, pixels.
        height: frame height, pixels.
        camera: ``None`` (tracks the torso), a :class:`~legoh_rl.envs.render.TrackingCamera`, a
            model camera's name or id, or a ``mujoco.MjvCamera``.
        **cfg: other :class:`~legoh_rl.envs.config.HikingEnvConfig` fields.

    ``metadata["render_fps"]`` is the control rate (50 with the default timestep and decimation):
    one frame per step plays at real time.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, robot: str = "h1", mode: str = "oracle", trails=None, render_mode: str | None = None,
                 width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT, camera=None, **cfg) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer number of pixels, got {value!r}")
        config = replace(HikingEnvConfig(), robot=robot, mode=mode, num_envs=1, **cfg)
        self.env = HikingEnv(config, trails=trails)
        self.render_mode = render_mode
        self.render_size = (int(height), int(width))
        self.camera = camera
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.dt}
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

    def render(self) -> np.ndarray | None:
        """The robot now, as (height, width, 3) uint8 RGB with ``render_mode="rgb_array"``.

        Returns None (with Gymnasium's warning) when the env was made without a render mode.

        Raises:
            RenderingUnavailableError: no OpenGL context (names MUJOCO_GL and what to install).
        """
        if self.render_mode is None:
            gym.logger.warn("render() was called without a render mode; make the env with "
                            "gymnasium.make(..., render_mode='rgb_array') to get frames")
            return None
        height, width = self.render_size
        return self.env.render(0, width=width, height=height, camera=self.camera)

    def close(self) -> None:
        """Free the renderer's OpenGL context, if any."""
        self.env.close(raise_if_closed=False)


def _as_td(env: HikingEnv, action: np.ndarray):
    from tensordict import TensorDict

    return TensorDict({"action": torch.as_tensor(action, device=env.device)}, batch_size=env.batch_size, device=env.device)
