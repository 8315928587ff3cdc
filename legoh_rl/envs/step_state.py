"""The per-world state of a :class:`~legoh_rl.envs.hiking.HikingEnv` step, for both backends.

:class:`StepState` owns everything a step keeps per world and does to it: the buffers (goals,
actions and their history, the feet's clocks, the episode clock, the perception tick, the
episode constants of each world's trail, the episode metrics, the last observations), the row
resets, the action handling (bad rows, clipping, the delay, the PD targets with the gait
clock's feed-forward), the goal tracking, rewards, episode ends and observations it inherits
from :class:`~legoh_rl.envs.step_quantities.StepQuantities`, and the output tensordict. It is
written once against the array API (:mod:`legoh_rl.envs.array_api`): with ``device=None`` its
arrays are float64 numpy arrays on the host, read from the simulation's host arrays (the host
step); with a torch device they are float32 tensors there, read from MuJoCo Warp's own arrays
(the device-resident step, ``HikingEnvConfig.resident``, docs/gpu_physics.md). The env's step
(:meth:`HikingEnv._step`) is the same for both.

What differs with where the arrays live is confined to a few places, each written at its own spot:

* the body state: the native kernel on the host (when it can read the terrain's grids), the
  Python path (:class:`~legoh_rl.envs.body_state.BodyStateReader`) on a device;
* the terrain lookups: :class:`~legoh_rl.envs.device_terrain.HostTerrain` or
  :class:`~legoh_rl.envs.device_terrain.DeviceTerrain`;
* the host's mirrors of the episode clock and the perception tick (:attr:`StepState.host_episode_step`,
  :attr:`StepState.host_tick`: the pushes and the camera are scheduled on the host without a
  read from the device; on the host they are the state's own arrays);
* ended episodes reach the curriculum right after the step on the host, at their worlds' reset
  on a device (:meth:`StepState.ended_episodes`: reading them at every step would be a second
  wait for the device per step);
* a host-marched depth image is copied to the device (:meth:`StepState.take_depth`).

Numerics: the host computes in float64 from the simulation's float64 state; a device in float32
(the PD targets in float64 on both, rounded once to the simulation's dtype), so the two agree to
float32 rounding (tests/test_resident_step.py holds them to each other).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.body_state import BodyStateReader
from legoh_rl.envs.device_terrain import DeviceTerrain, HostTerrain
from legoh_rl.envs.gait import swing_joints, swing_reference
from legoh_rl.envs.metrics import METRIC_NAMES, EpisodeMetrics
from legoh_rl.envs.sensors import foot_scan, foot_scan_blocks, scandot_offsets
from legoh_rl.envs.step_quantities import StepQuantities

__all__ = ["StepState"]


class StepState(StepQuantities):
    """The per-world buffers, resets, action handling and output of a hiking step, on the host
    (numpy) or on a torch device.

    Args:
        cfg: the env's :class:`~legoh_rl.envs.config.HikingEnvConfig` (the env replaces
            :attr:`cfg` when its feed-forward gain changes).
        robot: the :class:`~legoh_rl.envs.robots.RobotSpec`.
        built: the compiled model (joint addresses, feet, sensors, joint ranges).
        trails: the trail source.
        worlds: the simulation (:class:`~legoh_rl.envs.physics.BatchedWorlds` or
            :class:`~legoh_rl.envs.warp_physics.WarpWorlds`).
        weights: the reward weights by term.
        dt: control step, s.
        max_steps: control steps of an episode before it is truncated.
        privileged_width: columns of the privileged randomised dynamics (5 + A).
        camera_depth: the camera's image buffer ((N, 1, H, W): numpy on the host, a tensor when
            Warp casts it), or None without a camera.
        device: None for numpy arrays on the host; the simulation's torch device for tensors there.

    Arrays (N worlds, A actions, G goal slots; numpy float64 or tensors float32 on :attr:`device`,
    ints int64): the episode constants ``tile`` (N,), ``goals`` (N, G, 3) (expert goals, then P_B),
    ``num_goals`` (N,), ``start``/``end``/``waypoint`` (N, 3), ``privileged_dr`` (N, 5 + A); the
    per-step state ``goal_idx`` (N,), ``episode_step`` (N,), ``action``/``action_prev`` (N, A),
    ``action_hist`` (N, D + 1, A) newest first, ``dq_prev``/``torques_prev`` (N, A),
    ``feet_air_time`` (N, 2), ``last_contact`` (N, 2) bool, ``feet_xy_prev`` (N, 2, 2), ``tick``
    (N,) bool, ``metrics`` (:class:`EpisodeMetrics`), ``depth`` (N, 1, H, W) or None; and the
    constants ``q_default`` (A,) (``q_default64`` in float64), ``q_soft_limits`` (A, 2),
    ``hip_idx``, ``scandot_xy`` (K, 2), ``foot_scan_xy``, the foot scan's blocks of points
    (:func:`~legoh_rl.envs.sensors.foot_scan_blocks`, each (K_b, 2); empty without ``cfg.foot_scan``), ``tile_level``/``tile_category`` (T,); ``xquat`` (N, nbody, 4) is the simulation's live
    body orientations.
    """

    def __init__(self, cfg, robot, built, trails, worlds, weights: dict, dt: float, max_steps: int,
                 privileged_width: int, camera_depth=None, device: torch.device | None = None) -> None:
        self.cfg, self.robot, self.weights, self.dt, self.max_steps = cfg, robot, weights, dt, max_steps
        self.worlds = worlds
        self.device = device
        N, A = cfg.num_envs, robot.num_actions
        self.A = A
        if device is None:
            self.xp = np
            self.float = np.float64
            self.body = BodyStateReader(worlds, built, HostTerrain(trails), robot.foot_rest_height)
        else:
            self.xp = namespace_of(torch.zeros(0, device=device))
            self.float = torch.float32
            terrain = DeviceTerrain(trails, device, pits="feet_in_pit" in weights)
            self.body = BodyStateReader(worlds.views, built, terrain, robot.foot_rest_height)
        self.terrain = self.body.terrain

        # constants: the host's numpy values, and their copies in the state's namespace
        self.q_default_host = np.array(robot.default_joint_pos, dtype=np.float64)
        jr = built.joint_range
        mid, half = jr.mean(axis=1), (jr[:, 1] - jr[:, 0]) / 2
        self.q_soft_limits_host = np.stack([mid - 0.95 * half, mid + 0.95 * half], axis=1)
        self.q_default = self.from_host(self.q_default_host)
        self.q_default64 = self.from_host(self.q_default_host, np.float64)
        self.q_soft_limits = self.from_host(self.q_soft_limits_host)
        self.hip_idx = self.from_host(built.hip_idx, np.int64)
        self.scandot_xy = self.from_host(scandot_offsets())
        # the foot scan's points and the feet's orientations it reads (live arrays, as body.arrays)
        self.foot_scan_xy = tuple(self.from_host(b) for b in foot_scan_blocks(cfg.foot_scan_far)) if cfg.foot_scan else ()
        self.xquat = worlds.xquat if device is None else worlds.views["xquat"]
        self.tile_level = self.from_host(trails.tile_level, np.int64)
        self.tile_category = self.from_host(trails.tile_category, np.int64)
        # cfg.category_reward_scales as term -> (number of the trails' categories,) scale, 1 where unnamed
        self.category_scales = {
            term: self.from_host([cfg.category_reward_scales.get(c, {}).get(term, 1.0) for c in trails.categories])
            for term in sorted({t for scales in cfg.category_reward_scales.values() for t in scales})}
        self.goal_offsets = self.from_host(np.arange(cfg.num_goals), np.int64)
        self.world_index = self.from_host(np.arange(N), np.int64)
        self.swing_joints = swing_joints(robot.leg_joints) if cfg.gait_period else None

        G = trails.tile_goals.shape[1] + 1
        self.tile = self.zeros(N, dtype=np.int64)
        self.goals = self.zeros(N, G, 3)
        self.num_goals = self.from_host(np.ones(N), np.int64)
        self.start, self.end, self.waypoint = self.zeros(N, 3), self.zeros(N, 3), self.zeros(N, 3)
        self.privileged_dr = self.zeros(N, privileged_width)
        self.goal_idx = self.zeros(N, dtype=np.int64)
        self.episode_step = self.zeros(N, dtype=np.int64)
        self.action, self.action_prev = self.zeros(N, A), self.zeros(N, A)
        self.action_hist = self.zeros(N, cfg.domain_rand.delay_steps + 1, A)
        self.dq_prev, self.torques_prev = self.zeros(N, A), self.zeros(N, A)
        self.feet_air_time = self.zeros(N, 2)
        self.last_contact = self.zeros(N, 2, dtype=bool)
        self.feet_xy_prev = self.zeros(N, 2, 2)
        self.tick = self.from_host(np.ones(N, dtype=bool))
        self.metrics = EpisodeMetrics(N, device=device)
        # episodes that ended and have not reached the curriculum yet: ended, (progress, expected, success)
        self.ended = self.zeros(N, dtype=bool)
        self.ended_stats = self.zeros(N, 3)
        #: the host's copies of the episode clock and the perception tick (the state's own arrays
        #: on the host): pushes and camera frames are scheduled from them without reading the device
        self.host_episode_step = self.episode_step if device is None else np.zeros(N, dtype=np.int64)
        self.host_tick = self.tick if device is None else np.ones(N, dtype=bool)
        #: worlds held still until their next reset (:meth:`hold`): the state's and the host's copy
        self.held = self.zeros(N, dtype=bool)
        self.host_held = self.held if device is None else np.zeros(N, dtype=bool)
        # the depth images the observations read: the camera's own buffer where it lives in this
        # namespace (or on the host step), else a copy on the device refreshed on rendered rows
        self.depth = camera_depth
        if device is not None and camera_depth is not None and not (
                isinstance(camera_depth, torch.Tensor) and camera_depth.device == torch.device(device)):
            self.depth = torch.ones(tuple(camera_depth.shape), dtype=torch.float32, device=device)
        self._obs: dict = {}  # the last observations, updated in place by partial resets

    @property
    def scandots_width(self) -> int:
        """Columns of the ``scandots`` observation: K scandots, then 2 K_b foot-scan heights per
        block of ``foot_scan_xy`` (with ``cfg.foot_scan``)."""
        return int(self.scandot_xy.shape[0]) + sum(2 * int(b.shape[0]) for b in self.foot_scan_xy)

    # ------------------------------------------------------------------ arrays
    def zeros(self, *shape: int, dtype=None):
        """Zeros of ``shape`` in this state's namespace (the state's float dtype by default; a numpy
        dtype or ``bool`` otherwise)."""
        if self.device is None:
            return np.zeros(shape, dtype=self.float if dtype is None else dtype)
        return torch.zeros(shape, dtype=self.float if dtype is None else _torch_dtype(dtype), device=self.device)

    def from_host(self, a, dtype=None):
        """A host array in this state's namespace (as is on the host; a float array in the state's
        float dtype unless ``dtype`` names another)."""
        a = np.asarray(a)
        if self.device is None:
            return a if dtype is None else np.asarray(a, dtype=dtype)
        if dtype is None:
            dtype = self.float if np.issubdtype(a.dtype, np.floating) else _torch_dtype(a.dtype)
        else:
            dtype = _torch_dtype(dtype)
        return torch.as_tensor(a).to(device=self.device, dtype=dtype)

    def rows(self, ids: np.ndarray):
        """World indices ``ids`` (n,) (numpy) as an index of this state's arrays."""
        return ids if self.device is None else torch.as_tensor(np.asarray(ids, dtype=np.int64), device=self.device)

    @staticmethod
    def to_host(x) -> np.ndarray | None:
        """An array of this state as a host numpy array (as is on the host), or None for None."""
        return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else x

    # ------------------------------------------------------------------ state and gait clock
    def read_state(self, rows=None) -> dict:
        """The body state of every world, or of worlds ``rows`` (an index of this state's arrays),
        as :class:`~legoh_rl.envs.body_state.BodyStateReader` reads it, plus ``gait_phase`` (n,)
        float64 or None."""
        state = self.body.read(rows, self.end)
        phase = self.gait_phase()
        state["gait_phase"] = None if phase is None else phase[slice(None) if rows is None else rows]
        return state

    def host_state(self, ids=None) -> dict:
        """:meth:`read_state` of worlds ``ids`` (all if None) as host numpy arrays: float64 (bool
        for the contact flags)."""
        rows = None if ids is None else self.rows(np.asarray(ids, dtype=np.int64).reshape(-1))
        state = self.read_state(rows)
        if self.device is None:
            return state
        out = {}
        for key, value in state.items():
            value = self.to_host(value)
            out[key] = value if value is None or value.dtype == bool else value.astype(np.float64)
        return out

    def gait_phase(self):
        """(N,) float64 phase in [0, 1) of each world's gait clock (episode time / period), or None
        without a clock (float64 on both backends: the clock's stance thresholds cut the same)."""
        period = self.cfg.gait_period
        if not period:
            return None
        return self.xp.astype(self.episode_step, self.xp.float64) * self.dt / period % 1.0

    def gait_reference(self, phase=None):
        """(N, A) float64 leg-joint targets of the clock's swing reference (default pose + offsets)
        at ``phase`` (default: the current :meth:`gait_phase`), or None without a clock."""
        phase = self.gait_phase() if phase is None else phase
        if phase is None:
            return None
        return self.q_default64 + swing_reference(phase, self.swing_joints, self.A, self.cfg.gait_amplitude)

    def set_episode_step(self, steps: np.ndarray) -> None:
        """Set every world's episode clock to ``steps`` (N,) int (the state's and the host's copy)."""
        self.host_episode_step[...] = steps
        if self.host_episode_step is not self.episode_step:
            self.episode_step[...] = self.from_host(steps, np.int64)

    # ------------------------------------------------------------------ resets
    def reset_rows(self, ids: np.ndarray, tile: np.ndarray, goals: np.ndarray, num_goals: np.ndarray,
                   start: np.ndarray, end: np.ndarray, waypoint: np.ndarray, privileged_dr: np.ndarray) -> None:
        """Start new episodes in worlds ``ids`` (n,) (their simulation already reset): the episode
        constants the env drew on the host (``tile`` (n,), ``goals`` (n, G, 3), ``num_goals``
        (n,), ``start``/``end``/``waypoint`` (n, 3), ``privileged_dr`` (n, 5 + A)) are written,
        the per-step state cleared, the feet's positions taken and a depth frame asked for."""
        rows = self.rows(ids)
        for dst, src in ((self.tile, tile), (self.goals, goals), (self.num_goals, num_goals), (self.start, start),
                         (self.end, end), (self.waypoint, waypoint), (self.privileged_dr, privileged_dr)):
            dst[rows] = self.from_host(src, None if dst.dtype == self.float else np.int64)
        for buf in (self.goal_idx, self.episode_step, self.action, self.action_prev, self.action_hist,
                    self.dq_prev, self.torques_prev, self.feet_air_time):
            buf[rows] = 0
        self.last_contact[rows] = False
        self.feet_xy_prev[rows] = self.body.arrays["xpos"][rows][:, self.body.index["foot_bodies"], :2]
        self.metrics.reset(rows)
        self.tick[rows] = True
        self.held[rows] = False
        self.host_episode_step[ids] = 0
        self.host_tick[ids] = True
        self.host_held[ids] = False

    def hold(self, ids: np.ndarray) -> None:
        """Hold worlds ``ids`` (n,) until their next reset (the state's and the host's copy): they
        tick no more (:meth:`update_tick`) and end no episode (:meth:`_score_step`)."""
        self.host_held[ids] = True
        if self.host_held is not self.held:
            self.held[self.rows(ids)] = True

    def held_mask(self):
        """The state's (N,) held mask when some world is held, else None (the usual step, unmasked)."""
        return self.held if self.host_held.any() else None

    def ended_episodes(self, ids: np.ndarray | None = None):
        """The ended episodes to hand to the curriculum now, as host arrays ``(ids, progress,
        expected, success)`` (n,) each, or None when there are none.

        ``ids=None`` (after a step): on the host every episode that ended; on a device none (they
        wait, on the device, for their worlds' reset). ``ids`` (at a reset): those of worlds ``ids``.
        """
        if ids is None:
            if self.device is not None:
                return None
            ids = np.flatnonzero(self.ended)
        rows = self.rows(ids)
        ended, stats = self.to_host(self.ended[rows]), self.to_host(self.ended_stats[rows])
        if not ended.any():
            return None
        self.ended[rows] = False
        ids = np.asarray(ids)[ended]
        stats = stats[ended].astype(np.float64)
        return ids, stats[:, 0], stats[:, 1], stats[:, 2] > 0

    def _episodes_ended(self, done, progress, expected, success) -> None:
        """Keep the progress, expected progress and success of the episodes that end where
        ``done`` (N,) for :meth:`ended_episodes`."""
        xp = self.xp
        stats = xp.stack([progress, expected, xp.astype(success, progress.dtype)], axis=1)
        self.ended_stats[...] = xp.where(done[:, None], stats, self.ended_stats)
        self.ended |= done

    # ------------------------------------------------------------------ the step
    def apply_action(self, action: torch.Tensor, delay: int):
        """Take the policy's ``action`` (N, A) (any float dtype and device; checked by the env):
        rows with NaN/inf are replaced by zeros, the rest clipped to ``action_clip``; it enters the
        action history, and the action ``delay`` steps old, scaled around the default pose, plus
        the gait clock's feed-forward swing, becomes the simulation's PD targets (computed in
        float64, rounded once to the simulation's dtype).

        Returns:
            ``(bad, num_bad)``: (N,) bool, the replaced rows, and their count (a 0-d array: read
            it after the physics, so that a device is not waited for here).
        """
        xp, clip = self.xp, self.cfg.action_clip
        if self.device is None:
            a = action.detach().to("cpu", torch.float64).numpy()  # any float dtype (bfloat16 has no numpy twin)
        else:
            a = action.detach().to(self.device, self.float)
        finite = xp.all(xp.isfinite(a), axis=1)
        bad = ~finite
        a = xp.clip(xp.where(finite[:, None], a, 0.0), -clip, clip)
        self.action_prev[...] = self.action
        self.action[...] = a
        self.action_hist[...] = xp.roll(self.action_hist, 1, axis=1)  # newest first
        self.action_hist[:, 0] = a
        applied = self.action_hist[:, min(delay, self.action_hist.shape[1] - 1)]
        targets = self.q_default64 + self.robot.action_scale * xp.astype(applied, xp.float64, copy=False)
        if self.cfg.gait_feedforward:  # the clock's swing at the phase the policy just observed
            targets = targets + self.cfg.gait_feedforward * (self.gait_reference() - self.q_default64)
        self.worlds.set_joint_targets(targets)
        return bad, xp.sum(bad)

    def advance_clock(self) -> None:
        """One control step on every world's episode clock (the state's and the host's copy)."""
        self.episode_step += 1
        if self.host_episode_step is not self.episode_step:
            self.host_episode_step += 1

    def update_tick(self, perception_every: int, global_step: int | None = None) -> None:
        """The perception tick of the step just taken (the state's and the host's copy): a depth
        frame every ``perception_every`` control steps of each world's episode, or, given the
        env's ``global_step`` count (``perception_clock="global"``), of that count, on every world
        at once (a world's reset renders its first frame besides). A held world never ticks."""
        if global_step is not None:
            on = global_step % perception_every == 0
            self.tick[...] = on
            if self.host_tick is not self.tick:
                self.host_tick[...] = on
        else:
            self.tick[...] = self.episode_step % perception_every == 0
            if self.host_tick is not self.tick:
                np.equal(self.host_episode_step % perception_every, 0, out=self.host_tick)
        if self.host_held.any():  # a held world takes no frame and its perception does not run
            self.tick &= ~self.held
            if self.host_tick is not self.tick:
                self.host_tick &= ~self.host_held

    def take_depth(self, camera_depth, which: np.ndarray) -> None:
        """Copy the rows of worlds ``which`` (N,) bool the camera just rendered into
        ``camera_depth`` to this state's depth (nothing to do when they are the same buffer)."""
        if self.depth is None or self.depth is camera_depth or not which.any():
            return
        if which.all():
            self.depth.copy_(torch.from_numpy(camera_depth))
        else:
            ids = np.flatnonzero(which)
            self.depth[self.rows(ids)] = torch.from_numpy(camera_depth[ids]).to(self.device)

    # ------------------------------------------------------------------ lookups of StepQuantities
    def _scandots(self, pos, yaw):
        return self.terrain.scandots(pos, yaw, self.scandot_xy, self.robot.base_height_target)

    def _foot_scan(self, sel):
        feet = self.body.index["foot_bodies"]
        pos, quat = self.body.arrays["xpos"][sel][:, feet], self.xquat[sel][:, feet]
        blocks = [foot_scan(pos, quat, xy, self.terrain.heights, self.robot.foot_rest_height) for xy in self.foot_scan_xy]
        return blocks[0] if len(blocks) == 1 else self.xp.concat(blocks, axis=1)

    def _pit_under(self, feet_xy):
        xp = namespace_of(feet_xy)
        return xp.reshape(self.terrain.pit(xp.reshape(feet_xy, (-1, 2))), (-1, 2))

    def _privileged_dr(self):
        return self.privileged_dr

    def _depth_rows(self, sel):
        if self.depth is None:
            return None
        if isinstance(self.depth, torch.Tensor) and isinstance(sel, np.ndarray):  # a host step, Warp's camera
            sel = torch.as_tensor(sel, device=self.depth.device)
        return self.depth[sel]

    # ------------------------------------------------------------------ output
    def to_td(self, obs: dict, episode: dict, info: tuple, flags: tuple, batch_size: torch.Size,
              device: torch.device, reward=None, reward_terms: dict | None = None) -> TensorDictBase:
        """The step/reset output on ``device``: observations, episode metrics, info
        (``diverged``, ``bad_action``), the (done, terminated, truncated) flags and, for a step,
        the reward and its terms; every value a fresh tensor (the state keeps updating its
        buffers in place), observations float32 (``perception_tick`` bool), the (N,) columns
        (N, 1).

        The columns of each dtype are stacked into one (K, N) array, one tensor whose rows are the
        (N, 1) values, so a step makes a handful of tensors rather than one per key. The
        tensordict is assembled without per-key validation (``TensorDict._new_unsafe``, as
        torchrl's own wrappers do): every shape and dtype here is fixed by construction and
        checked against the specs by the tests (``check_env_specs``).
        """
        def tensor(x, dtype) -> torch.Tensor:  # a fresh tensor of x, on `device`
            if isinstance(x, torch.Tensor):
                return x.to(_torch_dtype(dtype)).clone().to(device)
            return torch.from_numpy(np.array(x, dtype=dtype)).to(device)

        def rows(columns: list, dtype) -> tuple[torch.Tensor, ...]:  # K x (N,) -> K x (N, 1)
            if isinstance(columns[0], torch.Tensor):
                block = torch.stack(columns).to(_torch_dtype(dtype))
            else:
                block = torch.from_numpy(np.array(columns, dtype=dtype))
            return block.to(device).unsqueeze(-1).unbind(0)

        out: dict = {k: tensor(v, bool if k == "perception_tick" else np.float32) for k, v in obs.items()}
        names = [] if reward_terms is None else list(reward_terms)
        floats = rows([episode[k] for k in METRIC_NAMES] + [reward_terms[k] for k in names]
                      + ([] if reward is None else [reward]), np.float32)
        out["episode"] = dict(zip(METRIC_NAMES, floats, strict=False))
        out["episode"]["level"], out["episode"]["category"] = rows([episode["level"], episode["category"]], np.int64)
        if reward_terms is not None:
            out["reward_terms"] = dict(zip(names, floats[len(METRIC_NAMES):], strict=False))
        bools = rows([info[0], info[1], *flags], bool)
        out["info"] = {"diverged": bools[0], "bad_action": bools[1]}
        if reward is not None:
            out["reward"] = floats[-1]
        out["done"], out["terminated"], out["truncated"] = bools[2:]
        return TensorDict._new_unsafe(out, batch_size=batch_size, device=device)


_TORCH_DTYPES = {np.dtype(np.float32): torch.float32, np.dtype(np.float64): torch.float64,
                 np.dtype(np.int64): torch.int64, np.dtype(bool): torch.bool}


def _torch_dtype(dtype) -> torch.dtype:
    """The torch dtype of a numpy dtype (or ``bool``); a torch dtype as is."""
    return dtype if isinstance(dtype, torch.dtype) else _TORCH_DTYPES[np.dtype(dtype)]
