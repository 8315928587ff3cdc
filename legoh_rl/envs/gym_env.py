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

Gymnasium's vector API is backed by the batched env, one :class:`HikingEnv` with N worlds (not N
copies of the single-world env)::

    envs = gymnasium.make_vec("LegoH/Hike-H1-v0", num_envs=64, vectorization_mode="vector_entry_point")
    obs, infos = envs.reset(seed=0)            # obs["proprio"]: (64, 37) float32
    obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

See :class:`HikingVectorEnv` (autoreset mode, infos). The observation and action conversion is
shared by both classes (:func:`observation_space_of`, :func:`action_space_of`, :func:`numpy_obs`).
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from tensordict import TensorDict, TensorDictBase

from legoh_rl.envs.autoreset import reset_worlds, step_autoreset
from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.render import DEFAULT_HEIGHT, DEFAULT_WIDTH

__all__ = ["HikingGymEnv", "HikingVectorEnv", "action_space_of", "numpy_obs", "observation_space_of"]

_OBS_KEYS = ("proprio", "goal_gps", "waypoint_gps", "scandots", "privileged", "expert_goals", "depth")



def _render(wrapper, worlds, maker: str):
    """Frames of ``worlds`` (an index, or None for all) of a Gymnasium wrapper's batched env at its
    ``render_size`` and ``camera``; None, with Gymnasium's warning naming ``gymnasium.<maker>``,
    when it was made without a render mode."""
    if wrapper.render_mode is None:
        gym.logger.warn(f"render() was called without a render mode; make the env with "
                        f"gymnasium.{maker}(..., render_mode='rgb_array') to get frames")
        return None
    height, width = wrapper.render_size
    return wrapper.env.render(worlds, width=width, height=height, camera=wrapper.camera)

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
        _check_render_args(render_mode, width, height, self.metadata["render_modes"])
        self.env = _make_env(robot, mode, trails, num_envs=1, **cfg)
        self.render_mode = render_mode
        self.render_size = (int(height), int(width))
        self.camera = camera
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.dt}
        self.observation_space = observation_space_of(self.env)
        self.action_space = action_space_of(self.env)

    def _obs(self, td) -> dict:
        return {k: v[0] for k, v in numpy_obs(td, self.observation_space.spaces).items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(seed)
        td = self.env.reset()
        return self._obs(td), {}

    def step(self, action):
        action = np.asarray(action, dtype=np.float32)
        if action.size != self.env.A:
            raise ValueError(f"action must hold {self.env.A} values (shape {(self.env.A,)}), got shape {action.shape}")
        nxt = self.env.step(_as_td(self.env, action.reshape(1, -1)))["next"]
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
        return _render(self, 0, "make")

    def close(self) -> None:
        """Free the renderer's OpenGL context, if any."""
        self.env.close(raise_if_closed=False)


def _as_td(env: HikingEnv, action: np.ndarray):
    return TensorDict({"action": torch.as_tensor(action, device=env.device)}, batch_size=env.batch_size, device=env.device)


class HikingVectorEnv(VectorEnv):
    """N worlds of the hiking env behind Gymnasium's vector API: one batched :class:`HikingEnv`.

    ``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point", **kwargs)``
    builds it for every registered id (``"sync"``/``"async"`` would step N single-world envs, one
    at a time). Arguments as :class:`HikingGymEnv`, plus:

    Args:
        num_envs: N, the worlds stepped together.
        max_episode_steps: optional episode length in control steps: sets the env's
            ``episode_length_s`` to ``max_episode_steps * timestep * decimation``, so the env
            itself truncates (``truncations`` True) and reports the episode's metrics.

    Spaces: ``single_observation_space`` is :class:`HikingGymEnv`'s ``Dict`` of float32 boxes;
    ``observation_space`` batches it (``gymnasium.vector.utils.batch_space``): ``proprio``
    (N, 37) for H1, ``scandots`` (N, 132), ``expert_goals`` (N, 3, 2), ``depth`` (N, 1, H, W) in
    student mode, ...; ``action_space`` is a (N, A) float32 box in [-clip, clip].

    Autoreset: ``metadata["autoreset_mode"]`` is ``AutoresetMode.SAME_STEP``. A world whose
    episode ends at a step (``terminated | truncated``) is reset within that same ``step``, as
    the batched env is driven in training (one partial reset of the ended worlds, torchrl's
    ``step_and_maybe_reset``): the returned observation of that world is its new episode's
    first, and its last observation is in ``infos["final_obs"]``. NEXT_STEP would step every
    world but skip the ended ones on the next call, which a batched physics step cannot do
    without advancing them. ``reset(options={"reset_mask": mask})`` resets only the worlds of an
    (N,) bool mask.

    Step outputs: ``obs`` a dict of (N, ...) float32 arrays, ``rewards`` (N,) float64,
    ``terminations``/``truncations`` (N,) bool. ``infos`` follow the layout of Gymnasium's
    ``SyncVectorEnv`` (each key with an ``"_key"`` (N,) bool mask of the worlds that have it), so
    both vectorisation modes give the same data: ``infos["reward_terms"][name]`` (N,) float64
    for the worlds that did not end; for the ones that ended ``infos["final_obs"]`` (an (N,)
    object array holding their last observation dicts, None elsewhere) and
    ``infos["final_info"]``, holding their ``reward_terms`` and ``episode`` metrics (success,
    trail completion, ..., level, category: docs/metrics.md).

    Rendering: with ``render_mode="rgb_array"``, :meth:`render` returns a tuple of N (height,
    width, 3) uint8 frames, one per world.

    Example:
        >>> envs = gymnasium.make_vec("LegoH/Hike-H1-v0", num_envs=64, vectorization_mode="vector_entry_point")
        >>> obs, _ = envs.reset(seed=0)
        >>> obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())
        >>> rewards.shape, obs["proprio"].shape     # (64,), (64, 37)
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50, "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, robot: str = "h1", mode: str = "oracle", trails=None,
                 render_mode: str | None = None, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                 camera=None, max_episode_steps: int | None = None, **cfg) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        _check_render_args(render_mode, width, height, self.metadata["render_modes"])
        if max_episode_steps is not None:
            if isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, (int, np.integer)) \
                    or max_episode_steps < 1:
                raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
            if "episode_length_s" in cfg:
                raise ValueError(f"give max_episode_steps ({max_episode_steps}) or episode_length_s "
                                 f"({cfg['episode_length_s']}), not both")
            base = HikingEnvConfig()
            dt = cfg.get("timestep", base.timestep) * cfg.get("decimation", base.decimation)
            cfg["episode_length_s"] = int(max_episode_steps) * dt
        self.env = _make_env(robot, mode, trails, num_envs=int(num_envs), **cfg)
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.render_size = (int(height), int(width))
        self.camera = camera
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.dt}
        self.single_observation_space = observation_space_of(self.env)
        self.single_action_space = action_space_of(self.env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._keys = tuple(self.single_observation_space.spaces)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Reset every world (or, with ``options={"reset_mask": mask}``, the worlds of an (N,)
        bool numpy mask; the others keep their state and their last observations).

        Args:
            seed: an int seeds the env's one random stream (spawns, randomisation, noise) for
                all worlds; per-world seeds are not supported.

        Returns:
            ``(obs, {})``: obs a dict of (N, ...) float32 arrays.
        """
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise ValueError(f"seed must be an int or None (one random stream drives all {self.num_envs} worlds), "
                             f"got {seed!r}")
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(int(seed))
        mask = (options or {}).get("reset_mask")
        if mask is None:
            td = self.env.reset()
        else:
            if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(f"options['reset_mask'] must be a ({self.num_envs},) bool numpy array, got "
                                 f"{type(mask).__name__} {getattr(mask, 'shape', '')} {getattr(mask, 'dtype', '')}")
            if not mask.any():
                raise ValueError("options['reset_mask'] must contain at least one True value")
            td = reset_worlds(self.env, torch.from_numpy(mask))
        return numpy_obs(td, self._keys), {}

    def step(self, actions) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Step all worlds with (N, A) actions and reset the worlds whose episode ended (SAME_STEP).

        Returns:
            ``(obs, rewards (N,) float64, terminations (N,) bool, truncations (N,) bool, infos)``
            (see the class docstring for ``infos``).

        Raises:
            ValueError: ``actions`` is not (N, A).
        """
        n, a = self.num_envs, self.env.A
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (n, a):
            raise ValueError(f"actions must have shape {(n, a)} (num_envs, num_actions), got {actions.shape}")
        step, obs_td, done_t = step_autoreset(self.env, torch.from_numpy(actions))
        rewards = step.get("reward").reshape(n).cpu().numpy().astype(np.float64)
        terminations = step.get("terminated").reshape(n).cpu().numpy()
        truncations = step.get("truncated").reshape(n).cpu().numpy()
        done = done_t.cpu().numpy()
        terms = {k: v.reshape(n).cpu().numpy().astype(np.float64) for k, v in step.get("reward_terms").items()}
        infos: dict = {}
        live = ~done
        if live.any():
            infos["reward_terms"], infos["_reward_terms"] = _masked(terms, live), live
        if done.any():
            last = numpy_obs(step, self._keys)
            final_obs = np.full(n, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = {k: v[i] for k, v in last.items()}
            episode = {k: v.reshape(n).cpu().numpy().astype(np.float64) for k, v in step.get("episode").items()}
            infos["final_obs"], infos["_final_obs"] = final_obs, done
            infos["final_info"] = {"reward_terms": _masked(terms, done), "_reward_terms": done,
                                   "episode": _masked(episode, done), "_episode": done}
            infos["_final_info"] = done
        return numpy_obs(obs_td, self._keys), rewards, terminations, truncations, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """Every world now: a tuple of N (height, width, 3) uint8 RGB frames with
        ``render_mode="rgb_array"``; None (with Gymnasium's warning) without a render mode.

        Raises:
            RenderingUnavailableError: no OpenGL context (names MUJOCO_GL and what to install).
        """
        frames = _render(self, None, "make_vec")
        return None if frames is None else tuple(frames)

    def close_extras(self, **kwargs) -> None:
        """Free the renderer's OpenGL context, if any."""
        self.env.close(raise_if_closed=False)


def observation_space_of(env: HikingEnv) -> gym.spaces.Dict:
    """One world's observations as a Gymnasium ``Dict`` of float32 boxes (the env's observation
    keys among ``proprio``, ``goal_gps``, ``waypoint_gps``, ``scandots``, ``privileged``,
    ``expert_goals``, ``depth``; shapes without the batch dim, bounds from the specs)."""
    spec = env.observation_spec
    spaces = {}
    for key in _OBS_KEYS:
        if key not in spec.keys():
            continue
        s = spec[key]
        low = s.space.low[0].cpu().numpy() if hasattr(s, "space") and hasattr(s.space, "low") else -np.inf
        high = s.space.high[0].cpu().numpy() if hasattr(s, "space") and hasattr(s.space, "high") else np.inf
        spaces[key] = gym.spaces.Box(low=low, high=high, shape=tuple(s.shape[1:]), dtype=np.float32)
    return gym.spaces.Dict(spaces)


def action_space_of(env: HikingEnv) -> gym.spaces.Box:
    """One world's action: an (A,) float32 box in [-clip, clip]."""
    clip = env.cfg.action_clip
    return gym.spaces.Box(-clip, clip, shape=(env.A,), dtype=np.float32)


def numpy_obs(td: TensorDictBase, keys) -> dict[str, np.ndarray]:
    """The ``keys`` entries of an env output as float32 numpy arrays, (N, ...) each (on the host;
    no copy for CPU float32 tensors: the env writes fresh tensors at every step and reset)."""
    return {k: np.asarray(td.get(k).detach().cpu().numpy(), dtype=np.float32) for k in keys}


def _masked(values: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """Gymnasium's vector info layout: each (N,) value with the entries outside ``mask`` zeroed,
    and its ``"_name"`` mask."""
    out = {}
    for name, value in values.items():
        out[name] = np.where(mask, value, np.zeros((), dtype=value.dtype))
        out[f"_{name}"] = mask.copy()
    return out


def _check_render_args(render_mode: str | None, width, height, modes: list[str]) -> None:
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer number of pixels, got {value!r}")


def _make_env(robot: str, mode: str, trails, num_envs: int, **cfg) -> HikingEnv:
    config = replace(HikingEnvConfig(), robot=robot, mode=mode, num_envs=num_envs, **cfg)
    return HikingEnv(config, trails=trails)
