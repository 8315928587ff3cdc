"""HikingEnv: the natively batched TorchRL environment of humanoid hiking.

One :class:`HikingEnv` steps ``num_envs`` MuJoCo worlds of one robot on one trail grid. Every
quantity is an ``(N, ...)`` array: observations, rewards, terminations, resets and metrics are
computed for all worlds at once, with no Python loop over worlds.

Keys (docs/observations.md has every layout and scale; docs/keys.md the contract):

* observations: ``proprio``, ``goal_gps``, ``waypoint_gps``, ``scandots``, ``privileged``,
  ``expert_goals``, ``perception_tick``, and ``depth`` when the camera is on;
* ``("reward_terms", name)``: each weighted reward term of this step (reward-spec entries beside
  ``reward``, so in ``"next"`` only; :attr:`HikingEnv.reward_key` is ``"reward"``);
* ``("episode", metric)``: the six paper metrics of episodes that end at this step (read them
  where ``done`` is True; 0, or NaN for ``time_to_reach``, elsewhere), plus ``level`` and
  ``category`` of the trail;
* ``("info", "diverged")``: the world's physics diverged and was reset (the episode is
  truncated); ``("info", "bad_action")``: the action held NaN/inf and was replaced by zeros.

Over 500 lines because it is the env's whole public face in one class (specs, step and reset,
the evaluation protocol's pins, rendering, checkpoint state); the step's per-world state and
arithmetic live in :mod:`legoh_rl.envs.step_state` and :mod:`legoh_rl.envs.step_quantities`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Protocol

import mujoco
import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from legoh_rl.envs.config import ANG_VEL_SCALE, DOF_VEL_SCALE, LIN_VEL_SCALE, HikingEnvConfig
from legoh_rl.envs.curriculum import Curriculum, world_categories
from legoh_rl.envs.metrics import METRIC_NAMES
from legoh_rl.envs.obstacle_rays import ObstacleRayCaster
from legoh_rl.envs.physics import BatchedWorlds
from legoh_rl.envs.randomization import DomainRandomizer
from legoh_rl.envs.render import (
    DEFAULT_HEIGHT,
    DEFAULT_WIDTH,
    TrackingCamera,
    WorldRenderer,
    add_route_markers,
    build_render_model,
)
from legoh_rl.envs.rewards import reward_weights
from legoh_rl.envs.robots import OBSTACLE_GEOM_GROUP, build_model, get_robot_spec
from legoh_rl.envs.sensors import DepthCamera
from legoh_rl.envs.step_state import StepState
from legoh_rl.envs.threads import torch_threads
from legoh_rl.envs.warp_depth import WarpDepthCamera
from legoh_rl.envs.warp_physics import WarpWorlds

__all__ = ["HikingEnv", "TrailSource", "ANG_VEL_SCALE", "DOF_VEL_SCALE", "LIN_VEL_SCALE"]

def _cells(levels: np.ndarray, categories: np.ndarray) -> set[tuple[int, int]]:
    """The distinct (level, category) pairs of some worlds, (n,) int each, as a set.

    The set is filled with the pairs in the order of their first appearance among the worlds, so
    it iterates in the same order as a set built world by world: the tile draws, and with them
    every recorded run, keep their random stream.
    """
    span = int(categories.max()) + 1 if categories.size else 1
    codes = levels.astype(np.int64) * span + categories
    distinct, first = np.unique(codes, return_index=True)
    return {(int(c // span), int(c % span)) for c in distinct[np.argsort(first)]}


class _HostView:
    """An env attribute that reads the step state's array of the same name as a host numpy array
    (the array itself on the host, a copy from a device-resident step)."""

    def __init__(self, doc: str) -> None:
        self.__doc__ = doc + " (numpy; a copy on a device)"

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, env: HikingEnv | None, owner: type | None = None):
        if env is None:
            return self
        return env.step_state.to_host(getattr(env.step_state, self.name))


class TrailSource(Protocol):
    """What the env needs of a trail grid (``legoh_rl.envs.trails.TrailGrid`` implements it).

    Per-tile arrays (T tiles, G max goals): ``tile_level`` (T,) int, ``tile_category`` (T,) int
    (index into ``categories``), ``tile_start``, ``tile_end``, ``tile_waypoint`` (T, 3) world
    coordinates, ``tile_goals`` (T, G, 3) padded, ``tile_num_goals`` (T,) int.
    ``height_at`` is the surface (ground and obstacle tops), ``ground_height_at`` the bare ground
    (geom group 0; obstacles are in group 1). Optional faster lookups the env uses when present:
    ``height_around(xy, yaw, offsets)`` (the scandots), ``height_at_t``/``ground_height_at_t``
    (:class:`~legoh_rl.envs.height_map.HeightMap`, the depth camera), ``max_height_near``/
    ``min_height_near`` (the camera's march bounds), ``pit_at`` (the ``feet_in_pit`` term).
    """

    categories: tuple[str, ...]
    num_levels: int
    tile_level: np.ndarray
    tile_category: np.ndarray
    tile_start: np.ndarray
    tile_end: np.ndarray
    tile_waypoint: np.ndarray
    tile_goals: np.ndarray
    tile_num_goals: np.ndarray

    def add_to_spec(self, spec: mujoco.MjSpec) -> None: ...

    def height_at(self, xy: np.ndarray) -> np.ndarray: ...

    def ground_height_at(self, xy: np.ndarray) -> np.ndarray: ...

    def edge_at(self, xy: np.ndarray) -> np.ndarray: ...


class HikingEnv(EnvBase):
    """Batched humanoid hiking on procedurally generated trails (MuJoCo, TorchRL).

    Args:
        cfg: the :class:`~legoh_rl.envs.config.HikingEnvConfig`.
        trails: the terrain; ``None`` builds the trail grid of ``cfg`` (categories, all levels,
            ``cfg.variants`` variants, ``cfg.seed``).

    Shapes: ``batch_size = [N]``; ``action`` (N, A) in [-clip, clip]; ``reward`` (N, 1);
    ``done``/``terminated``/``truncated`` (N, 1) bool.

    Backends: the per-world state of the step, its resets, action handling and output live in a
    :class:`~legoh_rl.envs.step_state.StepState` (:attr:`step_state`): numpy arrays on the host,
    or, with ``cfg.step_on_device`` (MuJoCo Warp on a GPU), tensors on the simulation's device. The
    step itself is the same for both.

    Resets: a partial reset (a ``"_reset"`` (N, 1) mask, as torchrl's ``step_and_maybe_reset``
    sends) re-spawns and re-reads only the masked worlds; the other rows of its output are the
    observations of the last step, unchanged (the env keeps them), so a reset costs in proportion
    to the worlds it resets.

    Rendering: :meth:`render` returns uint8 RGB frames of chosen worlds, (N, H, W, 3) by default,
    from a camera that tracks each robot's torso, so torchrl's ``PixelRenderTransform`` and
    ``VideoRecorder`` work on this env as they are (docs/rendering.md).

    Example:
        >>> env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=8))
        >>> td = env.rollout(10)           # random actions
        >>> td["next", "proprio"].shape    # torch.Size([8, 10, 37])
    """

    batch_locked = True

    def __init__(self, cfg: HikingEnvConfig | None = None, trails: TrailSource | None = None) -> None:
        cfg = cfg or HikingEnvConfig()
        self.cfg = cfg
        self.robot = get_robot_spec(cfg.robot, freeze_ankle_roll=cfg.freeze_ankle_roll)
        if trails is None:
            trails = _default_trails(cfg)
        self.trails = trails
        bad = [lvl for lvl in cfg.levels if not 0 <= int(lvl) < trails.num_levels]
        if bad:
            raise ValueError(f"levels {bad} out of range; valid levels: {list(range(trails.num_levels))}")
        N = cfg.num_envs
        super().__init__(device=torch.device(cfg.device), batch_size=torch.Size([N]))
        self.built = build_model(self.robot, terrain=trails, timestep=cfg.timestep)
        if cfg.physics == "warp":
            self.worlds = WarpWorlds(self.built, N, decimation=cfg.decimation, num_threads=cfg.num_threads,
                                     device=cfg.device, resident=cfg.step_on_device)
        else:
            self.worlds = BatchedWorlds(self.built, N, decimation=cfg.decimation, num_threads=cfg.num_threads)
        self.dt = self.worlds.dt
        self.A = self.robot.num_actions
        self.max_steps = int(round(cfg.max_episode_s / self.dt))
        self.push_every = max(1, int(round(cfg.domain_rand.push_interval_s / self.dt)))
        self.randomizer = DomainRandomizer(cfg.active_domain_rand, self.worlds)
        self.weights = reward_weights(cfg.robot, cfg.reward_overrides, student=cfg.mode != "oracle")
        if "feet_in_pit" in self.weights and getattr(trails, "pit_at", None) is None:
            raise ValueError(f"reward term feet_in_pit needs trails with pit_at(xy); {type(trails).__name__} has none")
        for category, scales in cfg.category_reward_scales.items():
            unweighted = sorted(set(scales) - set(self.weights))
            if unweighted:
                raise ValueError(f"category_reward_scales.{category} scales {unweighted}, which carry no weight here "
                                 f"(weighted terms: {sorted(self.weights)})")
        self.camera = None
        if cfg.depth_enabled and self.depth_on_device:  # the simulation's exact rays, on its device
            self.camera = WarpDepthCamera(self.worlds, self.built.camera_id, cfg.depth_camera,
                                          self.robot.camera_fovy_deg, seed=cfg.seed)
        elif cfg.depth_enabled:  # obstacles are static and the same in every world: one caster
            caster = ObstacleRayCaster.from_model(self.worlds.model, group=OBSTACLE_GEOM_GROUP)
            self.camera = DepthCamera(cfg.depth_camera, self.robot.camera_fovy_deg, obstacle_caster=caster)
        self.rng = np.random.default_rng(cfg.seed)
        self.global_steps = 0
        self.diverged_total = 0
        self.bad_action_total = 0
        #: wall seconds spent since construction in ``step`` (``_step``), in its physics
        #: (``worlds.step``) and in resets (``_reset``): where a collector's env time goes
        self.time_spent = {"step": 0.0, "physics": 0.0, "reset": 0.0}

        self._tiles_by = {}
        for t in range(trails.tile_level.shape[0]):
            self._tiles_by.setdefault((int(trails.tile_level[t]), int(trails.tile_category[t])), []).append(t)
        self._tiles_by = {k: np.array(v) for k, v in self._tiles_by.items()}
        levels0 = self.rng.choice(np.asarray(cfg.levels, dtype=np.int64), size=N)
        self.curriculum = Curriculum(cfg.curriculum if not cfg.is_eval else type(cfg.curriculum)(enabled=False),
                                     trails.num_levels, levels0)
        self.world_category = world_categories(N, np.unique(trails.tile_category), cfg.category_weights)
        #: the camera's depth images (N, 1, H, W), refreshed on the worlds it renders: numpy when
        #: marched on the host, a tensor where Warp casts them; None without a camera
        self.depth = None
        if self.camera is not None:
            c = self.cfg.depth_camera
            if self.depth_on_device:  # the images stay where the simulation casts them
                self.depth = torch.ones((N, 1, c.height, c.width), dtype=torch.float32,
                                        device=self.worlds.torch_device)
            else:
                self.depth = np.ones((N, 1, c.height, c.width), dtype=np.float32)
        #: the per-world state of the step: on the host, or on the simulation's device (``cfg.step_on_device``)
        self.step_state = StepState(cfg, self.robot, self.built, trails, self.worlds, self.weights, self.dt,
                                    self.max_steps, self.randomizer.privileged().shape[1], camera_depth=self.depth,
                                    device=self.worlds.torch_device if cfg.step_on_device else None)
        self._make_specs()

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        N, A, dev = self.cfg.num_envs, self.A, self.device
        k = self.cfg.num_goals
        P = 3 + 5 + A
        obs = {
            "proprio": Unbounded(shape=(N, 3 + 2 + 3 * A + 2 + (2 if self.cfg.gait_period else 0)), device=dev),
            "goal_gps": Unbounded(shape=(N, 2), device=dev),
            "waypoint_gps": Unbounded(shape=(N, 2), device=dev),
            "scandots": Bounded(-1.0, 1.0, shape=(N, self.step_state.scandots_width), device=dev),
            "privileged": Unbounded(shape=(N, P), device=dev),
            "expert_goals": Bounded(-1.0, 1.0, shape=(N, k, 2), device=dev),
            "perception_tick": Binary(n=1, shape=(N, 1), dtype=torch.bool, device=dev),
            "episode": Composite(
                {
                    **{name: Unbounded(shape=(N, 1), device=dev) for name in METRIC_NAMES},
                    "level": Unbounded(shape=(N, 1), dtype=torch.int64, device=dev),
                    "category": Unbounded(shape=(N, 1), dtype=torch.int64, device=dev),
                },
                shape=(N,),
                device=dev,
            ),
            "info": Composite(
                {
                    "diverged": Binary(n=1, shape=(N, 1), dtype=torch.bool, device=dev),
                    "bad_action": Binary(n=1, shape=(N, 1), dtype=torch.bool, device=dev),
                },
                shape=(N,),
                device=dev,
            ),
        }
        if self.camera is not None:
            c = self.cfg.depth_camera
            obs["depth"] = Bounded(0.0, 1.0, shape=(N, 1, c.height, c.width), device=dev)
        self.observation_spec = Composite(obs, shape=(N,), device=dev)
        clip = self.cfg.action_clip
        self.action_spec = Bounded(-clip, clip, shape=(N, A), device=dev)
        # the weighted terms are the reward's components: reward entries, in "next" only (step_mdp
        # does not carry them into the next root, and a reset does not produce them)
        self.reward_spec = Composite(
            {
                "reward": Unbounded(shape=(N, 1), device=dev),
                "reward_terms": Composite(
                    {name: Unbounded(shape=(N, 1), device=dev) for name in self.weights}, shape=(N,), device=dev
                ),
            },
            shape=(N,),
            device=dev,
        )
        self.done_spec = Composite(
            {
                key: Binary(n=1, shape=(N, 1), dtype=torch.bool, device=dev)
                for key in ("done", "terminated", "truncated")
            },
            shape=(N,),
            device=dev,
        )

    # ------------------------------------------------------------------ torchrl API
    @property
    def reward_key(self) -> str:
        """The reward to optimise: ``"reward"``, (N, 1). The ``("reward_terms", name)`` entries of
        the reward spec are its weighted components (for logging); torchrl's default would refuse
        to pick among several reward keys."""
        return "reward"

    def _step_proc_data(self, next_tensordict_out: TensorDictBase) -> TensorDictBase:
        """torchrl's post-step processing without its reward reshaping: that loop looks every
        reward entry's spec up at every step (~0.1 ms for the 17 entries here) to reshape rewards
        given as (N,) into (N, 1); this env writes (N, 1) by construction (``check_env_specs``
        tests hold it to the specs). With ``run_type_checks`` torchrl's full processing runs."""
        if self.run_type_checks:
            return super()._step_proc_data(next_tensordict_out)
        self._complete_done(self.full_done_spec, next_tensordict_out)
        return next_tensordict_out

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        started = time.perf_counter()
        N, st = self.cfg.num_envs, self.step_state
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").detach().cpu().numpy().reshape(N).astype(bool, copy=False)
        ids = np.arange(N) if mask is None else np.flatnonzero(mask)
        self._settle(st.ended_episodes(ids))  # before the reset draws tiles from the new levels
        self._reset_worlds(ids)
        which = np.isin(np.arange(N), ids)  # a reset world gets a fresh depth frame
        self._render_depth(which)
        st.take_depth(self.depth, which)
        obs = st._refresh_observations(st.rows(ids))
        no = st.zeros(N, dtype=bool)
        out = st.to_td(obs, st._empty_episode(), info=(no, no), flags=(no, no, no), batch_size=self.batch_size,
                       device=self.device)
        self.time_spent["reset"] += time.perf_counter() - started
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        started = time.perf_counter()
        N, A, st = self.cfg.num_envs, self.A, self.step_state
        action = tensordict.get("action", None)
        if action is None:
            raise KeyError(f"HikingEnv.step needs an 'action' entry of shape {(N, A)}; the tensordict has "
                           f"{sorted(str(k) for k in tensordict.keys())}")
        if action.shape != (N, A):
            raise ValueError(f"action must have shape {(N, A)} (num_envs, num_actions), got {tuple(action.shape)}")
        if not action.dtype.is_floating_point:
            raise TypeError(f"action must be a floating-point tensor, got dtype {action.dtype}")
        # documented: rows with NaN/inf are replaced by zeros and counted
        bad_action, num_bad = st.apply_action(action, self.randomizer.delay_steps(self.global_steps))
        st.advance_clock()
        self.global_steps += 1
        self.randomizer.push(st.host_episode_step % self.push_every == 0, self.rng)
        physics = time.perf_counter()
        diverged_before = self.worlds.diverged_total
        held = st.held_mask()
        # (a resident simulation's one wait for the device: its divergence count)
        diverged = self.worlds.step(None if held is None else ~st.host_held)
        self.time_spent["physics"] += time.perf_counter() - physics
        self.diverged_total += self.worlds.diverged_total - diverged_before
        self.bad_action_total += int(num_bad)

        state, total, terms, episode, flags = st._score_step(diverged, held)
        self._settle(st.ended_episodes())
        st.update_tick(self.cfg.perception_every, self.global_steps if self.cfg.perception_clock == "global" else None)
        self._render_depth(st.host_tick)
        st.take_depth(self.depth, st.host_tick)
        obs = st._observations(state)
        st._obs.update(obs)
        out = st.to_td(obs, episode, info=(diverged, bad_action), flags=flags, batch_size=self.batch_size,
                       device=self.device, reward=total, reward_terms=terms)
        self.time_spent["step"] += time.perf_counter() - started
        return out

    # ------------------------------------------------------------------ episodes
    def hold(self, worlds) -> None:
        """Hold ``worlds`` still until their next reset: an evaluation's finished worlds, whose
        steps nobody reads, stop costing what a step costs.

        A held world ends no episode (its ``done``, ``terminated`` and ``truncated`` stay False,
        so it is never auto-reset), takes no depth frame and never ticks (``perception_tick``
        False: a :class:`~legoh_rl.transforms.PerceptionHold` policy leaves its perception
        out), and on the C MuJoCo physics its simulation is not advanced (Warp's one launch
        steps every world). Its other outputs (observations, reward) are computed as usual and
        meaningless. The other worlds' steps are exactly what they would be without the hold.
        A reset of the world (``env.reset()``, or its row of ``_reset``) releases it; the hold
        is not part of :meth:`state_dict`.

        Args:
            worlds: a world index, a sequence of them or an (N,) bool mask (as :meth:`render`).

        Raises:
            ValueError: ``worlds`` is None, an index lies outside ``[0, N)``, or a mask has the
                wrong shape.
        """
        if worlds is None:
            raise ValueError("hold needs the worlds to hold (an index, indices or an (N,) bool mask), got None")
        ids, _ = self._world_ids(worlds)
        if ids.size:
            self.step_state.hold(ids)

    @property
    def held(self) -> np.ndarray:
        """(N,) bool, the worlds :meth:`hold` holds now (a copy)."""
        return self.step_state.host_held.copy()

    def _reset_worlds(self, ids: np.ndarray) -> None:
        """Start new episodes in worlds ``ids`` (n,): draw their trail tiles, spawn poses and
        randomised dynamics from the env's stream (on the host, in this order), reset their
        simulation and hand the episode constants to the step state."""
        if ids.size == 0:
            return
        tr, cfg, n = self.trails, self.cfg, ids.size
        levels, cats = self.curriculum.levels[ids], self.world_category[ids]
        tiles = np.empty(n, dtype=np.int64)
        for key in _cells(levels, cats):  # one draw per (level, category) cell, not per world
            sel = (levels == key[0]) & (cats == key[1])
            choices = self._tiles_for(*key)
            tiles[sel] = choices[self.rng.integers(0, choices.size, size=int(sel.sum()))]  # = rng.choice, faster
        start = tr.tile_start[tiles]
        ng = tr.tile_num_goals[tiles]
        G = tr.tile_goals.shape[1]
        goals = np.zeros((n, G + 1, 3))  # expert goals followed by P_B
        goals[:, :G] = tr.tile_goals[tiles]
        goals[np.arange(n), ng] = tr.tile_end[tiles]  # P_B is the last goal

        jitter = 0.0 if cfg.is_eval else 1.0
        xy = start[:, :2] + jitter * self.rng.uniform(-cfg.spawn_jitter_xy, cfg.spawn_jitter_xy, size=(n, 2))
        first = goals[:, 0, :2] - xy
        yaw = np.arctan2(first[:, 1], first[:, 0]) + jitter * self.rng.uniform(
            -cfg.spawn_jitter_yaw, cfg.spawn_jitter_yaw, size=n
        )
        qpos = np.tile(self.built.default_qpos, (n, 1))
        qpos[:, 0:2] = xy
        qpos[:, 2] = tr.height_at(xy) + self.robot.spawn_height
        qpos[:, 3] = np.cos(yaw / 2)
        qpos[:, 4:6] = 0.0
        qpos[:, 6] = np.sin(yaw / 2)
        self.randomizer.randomize(ids, self.rng)
        self.worlds.reset(ids, qpos=qpos)
        self.step_state.reset_rows(ids, tile=tiles, goals=goals, num_goals=ng + 1, start=start,
                                   end=tr.tile_end[tiles], waypoint=tr.tile_waypoint[tiles],
                                   privileged_dr=self.randomizer.privileged()[ids])

    def _tiles_for(self, level: int, category: int) -> np.ndarray:
        tiles = self._tiles_by.get((level, category))
        if tiles is None:  # this category lacks the level: any tile of the level
            tiles = np.flatnonzero(self.trails.tile_level == level)
        return tiles

    def _settle(self, ended: tuple | None) -> None:
        """Hand ended episodes ``(ids, progress, expected, success)`` (n,) each
        (:meth:`StepState.ended_episodes`) to the curriculum."""
        if ended is not None:
            self.curriculum.update(*ended, self.rng)

    # ------------------------------------------------------------------ state, rewards, obs
    def read_state(self, ids: np.ndarray | None = None) -> dict:
        """The worlds' current physical state as numpy arrays (observations and rewards start here).

        ``ids`` (n,) restricts it to those worlds (rows in that order); default: all N worlds.
        Keys (N = num_envs, or n): those of :class:`~legoh_rl.envs.body_state.BodyStateReader`
        (``pos`` (N, 3), ``rot`` (N, 3, 3), ``roll``/``pitch``/``yaw`` (N,), velocities, ``q``/``dq``/
        ``torques`` (N, A), ``contact`` (N, 2) bool, ``foot_lift`` (N, 2) m, ``base_height`` (N,) m,
        ``goal_dist`` (N,) m to P_B, ...) and ``gait_phase`` (N,) or None; float64 (bool for the
        contact flags) on either backend. Analysis tools (recipes/gait_stats.py) read it too.
        """
        return self.step_state.host_state(ids)

    def gait_reference(self, phase: np.ndarray | None = None) -> np.ndarray | None:
        """(N, A) leg-joint targets of the gait clock's swing reference (default pose + offsets) at
        ``phase`` (default: the current :meth:`gait_phase`), or None without a clock (numpy)."""
        st = self.step_state
        return st.to_host(st.gait_reference(None if phase is None else st.from_host(phase, np.float64)))

    def set_gait_feedforward(self, gain: float) -> None:
        """Set the gain of the clock's swing reference in the PD targets from the next step on
        (``HikingEnvConfig.gait_feedforward``; annealing it to 0 leaves a policy without it).

        Raises:
            ValueError: a negative gain, or a positive one without a gait clock (names the value).
        """
        if float(gain) != self.cfg.gait_feedforward:
            self.cfg = dataclasses.replace(self.cfg, gait_feedforward=float(gain))  # validated there
            self.step_state.cfg = self.cfg

    def gait_phase(self) -> np.ndarray | None:
        """(N,) phase in [0, 1) of each world's gait clock (episode time / period), or None (numpy)."""
        return self.step_state.to_host(self.step_state.gait_phase())

    # ------------------------------------------------------------------ the step state, read on the host
    @property
    def episode_step(self) -> np.ndarray:
        """(N,) int control steps since each world's reset (the host's copy: write it through
        :meth:`StepState.set_episode_step`)."""
        return self.step_state.host_episode_step

    @property
    def q_default(self) -> np.ndarray:
        """(A,) the robot's default joint positions, rad (the PD targets of a zero action)."""
        return self.step_state.q_default_host

    tile = _HostView("(N,) int each world's trail tile.")
    start = _HostView("(N, 3) each world's P_A.")
    end = _HostView("(N, 3) each world's P_B.")
    waypoint = _HostView("(N, 3) each world's trail waypoint.")
    goals = _HostView("(N, G, 3) each world's expert goals then P_B, valid up to ``num_goals``.")
    num_goals = _HostView("(N,) int goals of each world's trail, P_B included.")
    goal_idx = _HostView("(N,) int the goal each world walks to.")

    @property
    def depth_on_device(self) -> bool:
        """Whether depth is cast by MuJoCo Warp on the simulation's device and kept there as a
        torch tensor (``depth_camera.source=warp``; ``auto`` is the host march on either backend,
        the faster one measured on an H100: docs/gpu_physics.md, "Depth on the device")."""
        return self.cfg.depth_camera.source == "warp"

    def _render_depth(self, which: np.ndarray) -> None:
        if self.camera is None or not which.any():
            return
        if self.depth_on_device:  # Warp casts every world's rays at once; keep the ticking worlds' rows
            images = self.camera.render()
            if which.all():
                self.depth.copy_(images)
            else:
                rows = torch.as_tensor(np.flatnonzero(which), device=self.depth.device)
                self.depth[rows] = images[rows]
            return
        ids = np.flatnonzero(which)
        cam = self.built.camera_id
        self.worlds.refresh_host(ids)  # (a resident simulation's camera poses)
        # camera pose at the current state (kinematics of the last call)
        pos = self.worlds.cam_xpos[ids, cam]
        mat = self.worlds.cam_xmat[ids, cam].reshape(-1, 3, 3)
        with torch_threads(self.worlds.num_threads):  # the physics threads' cores are free now
            self.depth[ids] = self.camera.render(
                self.worlds.batch, pos, mat, ids,
                getattr(self.trails, "height_at_t", self.trails.height_at),
                getattr(self.trails, "ground_height_at_t", self.trails.ground_height_at),
                self.rng,
                z_max=self.trails.max_height_near(pos[:, :2]) if hasattr(self.trails, "max_height_near") else None,
                z_min=self.trails.min_height_near(pos[:, :2]) if hasattr(self.trails, "min_height_near") else None,
            )

    # ------------------------------------------------------------------ evaluation protocol
    def assign_tiles(self, levels: np.ndarray, categories: np.ndarray) -> None:
        """Pin each world to a trail level and category (an evaluation cell).

        Takes effect at each world's next reset; with the curriculum off (eval mode) the worlds
        stay in their cells. ``categories`` are indices into ``trails.categories``.

        Args:
            levels: (N,) int levels.
            categories: (N,) int category indices.
        """
        levels = np.asarray(levels, dtype=np.int64).reshape(-1)
        categories = np.asarray(categories, dtype=np.int64).reshape(-1)
        n = self.cfg.num_envs
        if levels.shape != (n,) or categories.shape != (n,):
            raise ValueError(f"need one level and one category per world ({n}), got {levels.shape}, {categories.shape}")
        if levels.min() < 0 or levels.max() >= self.trails.num_levels:
            raise ValueError(f"levels must lie in [0, {self.trails.num_levels}), got {np.unique(levels).tolist()}")
        known = np.unique(self.trails.tile_category)
        if not np.isin(categories, known).all():
            raise ValueError(f"category indices must be among {known.tolist()}, got {np.unique(categories).tolist()}")
        self.curriculum.levels[:] = levels
        self.world_category[:] = categories

    # ------------------------------------------------------------------ rendering
    def render(
        self,
        worlds: int | Sequence[int] | np.ndarray | torch.Tensor | None = None,
        width: int = DEFAULT_WIDTH,
        height: int = DEFAULT_HEIGHT,
        camera: TrackingCamera | str | int | mujoco.MjvCamera | None = None,
        route: bool = False,
    ) -> np.ndarray:
        """RGB frames of worlds at their current state (MuJoCo's off-screen ``mujoco.Renderer``).

        Frames are drawn with :attr:`render_model` (a sky, a gridded ground under a sun casting
        shadows, obstacles in contrasting colours); the physics is not touched.

        Args:
            worlds: ``None`` for every world, one world index, or a sequence (or (N,) bool mask)
                of worlds.
            width: frame width, pixels.
            height: frame height, pixels.
            camera: ``None`` for a camera that tracks each world's torso (3.5 m away, 20 degrees
                down); a :class:`~legoh_rl.envs.render.TrackingCamera` to set its distance,
                elevation, azimuth or body; a model camera's name or id (``"head_depth"`` is the
                robot's head camera); or a ``mujoco.MjvCamera``.
            route: draw each world's trail: P_A, the expert goals (the one being walked to in
                yellow, those reached in grey), the waypoint and P_B
                (:func:`~legoh_rl.envs.render.add_route_markers`).

        Returns:
            uint8 RGB frames: (n, height, width, 3) for ``None`` (n = N, so torchrl's
            ``PixelRenderTransform`` writes them as a ``pixels`` entry of the batch) or a
            sequence (n = its length), (height, width, 3) for one int world.

        Raises:
            ValueError: a world index out of [0, N) or a bad size or camera.
            RenderingUnavailableError: no OpenGL context; it names MUJOCO_GL and what to install.

        The OpenGL context is made on the first call and kept (one per frame size) until
        :meth:`close`. Without a display set ``MUJOCO_GL=egl`` before importing mujoco.

        Example:
            >>> frames = env.render()             # (N, 240, 320, 3) uint8
            >>> frame = env.render(0, 160, 120)   # (120, 160, 3)
        """
        ids, single = self._world_ids(worlds)
        renderer = self.__dict__.get("_renderer")
        if renderer is None or (renderer.width, renderer.height) != (width, height):
            if renderer is not None:
                renderer.close()
            self.__dict__["_renderer"] = None  # a plain attribute, not an nn.Module entry
            renderer = WorldRenderer(self.worlds, self.built.torso_body_id, height=height, width=width,
                                     model=self.render_model)
            self.__dict__["_renderer"] = renderer
        frames = renderer.render(ids, camera, decorate=self._draw_route if route else None)
        return frames[0] if single else frames

    @property
    def render_model(self) -> mujoco.MjModel:
        """The model frames are drawn with: the physics model built again with visual-only
        changes (:func:`~legoh_rl.envs.render.build_render_model`), made on first use and kept.
        The physics model itself is never changed for drawing."""
        model = self.__dict__.get("_render_model")
        if model is None:
            model = build_render_model(self.robot, self.trails, self.cfg.timestep, physics=self.worlds.model)
            self.__dict__["_render_model"] = model  # a plain attribute, not an nn.Module entry
        return model

    def _draw_route(self, world: int, scene: mujoco.MjvScene) -> None:
        """Add world ``world``'s trail markers to ``scene`` (:meth:`render` with ``route=True``)."""
        n = int(self.num_goals[world])
        add_route_markers(scene, self.start[world], self.goals[world, :n], current=int(self.goal_idx[world]),
                          waypoint=self.waypoint[world])

    def _world_ids(self, worlds) -> tuple[np.ndarray, bool]:
        """(n,) world indices of ``worlds`` (see :meth:`render`) and whether it was one int."""
        N = self.cfg.num_envs
        if worlds is None:
            return np.arange(N), False
        if isinstance(worlds, torch.Tensor):
            worlds = worlds.detach().cpu().numpy()
        single = isinstance(worlds, (int, np.integer)) or (isinstance(worlds, np.ndarray) and worlds.ndim == 0)
        arr = np.asarray(worlds)
        if arr.dtype == bool:
            if arr.shape != (N,):
                raise ValueError(f"a world mask must have shape ({N},), got {arr.shape}")
            return np.flatnonzero(arr), False
        if arr.size == 0:
            return np.zeros(0, dtype=np.int64), False
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"worlds must be None, an int, a sequence of ints or a bool mask, got {worlds!r}")
        ids = arr.astype(np.int64).reshape(-1)
        if ids.min() < 0 or ids.max() >= N:
            raise ValueError(f"world indices must lie in [0, {N}), got {ids.tolist()}")
        return ids, bool(single)

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Free the renderer's OpenGL context, if any, and mark the env closed."""
        renderer = self.__dict__.pop("_renderer", None)
        if renderer is not None:
            renderer.close()
        super().close(raise_if_closed=raise_if_closed)

    # ------------------------------------------------------------------ checkpoint state
    #: The exact states of the worker processes that step this env's worlds in slices
    #: (``collector.workers`` > 1: :class:`~legoh_rl.training.workers.WorkerEnvs` keeps them, this
    #: env then only mirrors their curriculum and counters); ``None`` when this env is stepped itself.
    slice_states: list[dict] | None = None

    def state_dict(self) -> dict:
        """Curriculum, rng and counters, for checkpoints (the physics state is not saved); with
        :attr:`slice_states`, also ``"workers"``: the K workers' own states."""
        state = {
            "curriculum": self.curriculum.state_dict(),
            "rng": self.rng.bit_generator.state,
            "global_steps": self.global_steps,
            "diverged_total": self.diverged_total,
            "bad_action_total": self.bad_action_total,
        }
        if self.slice_states is not None:
            state["workers"] = [dict(s) for s in self.slice_states]
        if isinstance(self.camera, WarpDepthCamera):  # its noise stream lives on the device
            state["depth_rng"] = self.camera.generator.get_state()
        return state

    def load_state_dict(self, state: dict, streams: bool = True) -> None:
        """Restore :meth:`state_dict` (its ``"workers"`` into :attr:`slice_states`, ``None`` without).

        Args:
            streams: also the random streams (this env's and the workers'); False keeps the
                env's own (seeded from its config) and leaves :attr:`slice_states` ``None``: a
                run branched from another's curriculum and counters with fresh randomness.
        """
        self.curriculum.load_state_dict(state["curriculum"])
        if streams:
            self.rng.bit_generator.state = state["rng"]
            if isinstance(self.camera, WarpDepthCamera) and "depth_rng" in state:
                self.camera.generator.set_state(state["depth_rng"])
        self.global_steps = int(state["global_steps"])
        self.diverged_total = int(state["diverged_total"])
        self.bad_action_total = int(state.get("bad_action_total", 0))  # absent in older checkpoints
        self.slice_states = state.get("workers") if streams else None


def _default_trails(cfg: HikingEnvConfig) -> TrailSource:
    from legoh_rl.envs.trail_source import trails_for

    return trails_for(cfg.categories, cfg.variants, cfg.seed, pit_depths=cfg.pit_depths)
