"""The device-resident step of :class:`~legoh_rl.envs.hiking.HikingEnv` (``HikingEnvConfig.resident``).

With MuJoCo Warp on a GPU, the host step copies every world's state to the host, computes the
observations and rewards there in numpy and sends the results back: about as much time as the
physics itself (docs/gpu_physics.md). :class:`ResidentStep` computes the same quantities as torch
tensors on the simulation's device, reading the simulation's own arrays
(:attr:`~legoh_rl.envs.warp_physics.WarpWorlds.views`) and the terrain's grids there
(:class:`~legoh_rl.envs.device_terrain.DeviceTerrain`). The reward terms, the gait clock and the
episode metrics are the host step's own functions, and the goals, reward inputs, episode ends and
observations the host step's own methods (:class:`~legoh_rl.envs.step_quantities.StepQuantities`),
all written once against the array API (:mod:`legoh_rl.envs.array_api`); the tests hold the two
paths to each other on Warp's CPU device (tests/test_resident_step.py).

What stays on the host, and crosses only where it must:

* resets: trail tiles, spawn poses and domain randomisation are drawn by the env's numpy stream as
  in the host step, and only the reset worlds' rows are sent (:meth:`ResidentStep.reset_rows`);
* the curriculum: an episode's progress is kept on the device when it ends and handed to the
  curriculum when its world is reset (:meth:`ResidentStep.settle_curriculum`), the same updates,
  in the same order, as the host step's (a reset follows every end in torchrl's rollouts);
* the episode clock (``episode_step``), the push schedule and the perception tick, which the host
  knows without reading anything back; the pushes' velocities are sent for the pushed rows;
* one count per step, of diverged worlds and bad actions (the step's only wait for the device);
* a depth image marched on the host (``depth_camera.source`` ``auto``/``host``) is sent to the
  device; ``warp`` casts it there.

Numerics: float32, as the simulation's state (the host step computes in float64 from the same
float32 state), so rewards agree to float32 rounding and flags agree but at exact thresholds.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from legoh_rl.envs.body_state import CONTACT_FORCE_THRESHOLD
from legoh_rl.envs.device_terrain import DeviceTerrain
from legoh_rl.envs.gait import swing_reference
from legoh_rl.envs.height_map import yaw_frame_points
from legoh_rl.envs.metrics import METRIC_NAMES, EpisodeMetrics
from legoh_rl.envs.sensors import quat_to_rotmat, roll_pitch_from_gravity
from legoh_rl.envs.step_quantities import StepQuantities

if TYPE_CHECKING:
    from legoh_rl.envs.hiking import HikingEnv

__all__ = ["ResidentStep"]

_F32 = torch.float32


class ResidentStep(StepQuantities):
    """Per-world step state and the step of a :class:`HikingEnv` whose worlds live on a device.

    Args:
        env: the env (its worlds a resident :class:`~legoh_rl.envs.warp_physics.WarpWorlds`);
            this object keeps a reference and reads the env's host-side state (config, trails,
            episode constants written by its resets, random stream, curriculum).

    Tensors (N worlds, A actions, G goals, on :attr:`device`): ``goal_idx`` (N,) int,
    ``episode_step`` (N,) int, ``action``/``action_prev`` (N, A), ``action_hist`` (N, D + 1, A),
    ``dq_prev``/``torques_prev`` (N, A), ``feet_air_time`` (N, 2), ``last_contact`` (N, 2) bool,
    ``feet_xy_prev`` (N, 2, 2), ``privileged_dr`` (N, 5 + A), the episode constants ``tile`` (N,),
    ``goals`` (N, G, 3), ``num_goals`` (N,), ``start``/``end``/``waypoint`` (N, 3), and
    ``metrics`` (an :class:`EpisodeMetrics` of tensors).
    """

    def __init__(self, env: HikingEnv) -> None:
        self.env = env
        self.worlds = env.worlds
        self.dt, self.robot, self.weights, self.max_steps = env.dt, env.robot, env.weights, env.max_steps
        dev = self.device = env.worlds.torch_device
        N, A = env.cfg.num_envs, env.A
        built, tr = env.built, env.trails

        def const(a, dtype=_F32) -> torch.Tensor:
            return torch.as_tensor(np.asarray(a), dtype=dtype, device=dev)

        self.terrain = DeviceTerrain(tr, dev, pits="feet_in_pit" in env.weights)
        self.q_default = const(env.q_default)
        self.q_default64 = const(env.q_default, torch.float64)
        self.q_soft_limits = const(env.q_soft_limits)
        self.hip_idx = const(built.hip_idx, torch.int64)
        self.qpos_adr = const(built.qpos_adr, torch.int64)
        self.dof_adr = const(built.dof_adr, torch.int64)
        self.act_ids = const(built.actuator_ids, torch.int64)
        self.foot_bodies = const(built.foot_body_ids, torch.int64)
        self.foot_cols = const(env.body.foot_force_cols, torch.int64)
        self.pen_cols = const(env.body.pen_force_cols, torch.int64)
        self.scandot_xy = const(env.scandot_xy)
        self.tile_level = const(tr.tile_level, torch.int64)
        self.tile_category = const(tr.tile_category, torch.int64)
        self.goal_offsets = torch.arange(env.cfg.num_goals, device=dev)
        self.world_index = torch.arange(N, device=dev)
        G = tr.tile_goals.shape[1] + 1

        def zeros(*shape, dtype=_F32) -> torch.Tensor:
            return torch.zeros(shape, dtype=dtype, device=dev)

        self.tile = zeros(N, dtype=torch.int64)
        self.goals = zeros(N, G, 3)
        self.num_goals = torch.ones(N, dtype=torch.int64, device=dev)
        self.start, self.end, self.waypoint = zeros(N, 3), zeros(N, 3), zeros(N, 3)
        self.goal_idx = zeros(N, dtype=torch.int64)
        self.episode_step = zeros(N, dtype=torch.int64)
        self.action, self.action_prev = zeros(N, A), zeros(N, A)
        self.action_hist = zeros(N, env.action_hist.shape[1], A)
        self.dq_prev, self.torques_prev = zeros(N, A), zeros(N, A)
        self.feet_air_time = zeros(N, 2)
        self.last_contact = zeros(N, 2, dtype=torch.bool)
        self.feet_xy_prev = zeros(N, 2, 2)
        self.privileged_dr = zeros(N, env.randomizer.privileged().shape[1])
        self.tick = torch.ones(N, dtype=torch.bool, device=dev)
        self.metrics = EpisodeMetrics(N, device=dev)
        # episodes that ended, waiting for their world's reset to reach the curriculum
        self.ended = zeros(N, dtype=torch.bool)
        self.ended_stats = zeros(N, 3)  # progress, expected, success
        self._obs: dict[str, torch.Tensor] = {}
        # a host-marched depth image's device copy, refreshed on the rows the camera rendered
        self.depth = None
        if isinstance(env.depth, np.ndarray):
            self.depth = torch.ones(env.depth.shape, dtype=_F32, device=dev)

    @property
    def cfg(self):
        """The env's config (read live: the env replaces it when its feedforward gain changes)."""
        return self.env.cfg

    # ------------------------------------------------------------------ resets
    def reset_rows(self, ids: np.ndarray) -> None:
        """Start new episodes in worlds ``ids`` (n,): the episode constants the env's host reset
        drew are sent for those rows, their per-step state cleared."""
        env = self.env
        rows = torch.as_tensor(ids, device=self.device)

        def send(dst: torch.Tensor, src: np.ndarray) -> None:
            dst[rows] = torch.as_tensor(src, dtype=dst.dtype).to(self.device)

        send(self.tile, env.tile[ids])
        send(self.goals, env.goals[ids])
        send(self.num_goals, env.num_goals[ids])
        send(self.start, env.start[ids])
        send(self.end, env.end[ids])
        send(self.waypoint, env.waypoint[ids])
        send(self.privileged_dr, env.randomizer.privileged()[ids])
        for buf in (self.goal_idx, self.episode_step, self.action, self.action_prev, self.action_hist, self.dq_prev,
                    self.torques_prev, self.feet_air_time, self.last_contact):
            buf[rows] = 0
        self.feet_xy_prev[rows] = self.worlds.views["xpos"][rows][:, self.foot_bodies, :2]
        self.metrics.reset(rows)
        self.tick[rows] = True

    def settle_curriculum(self, ids: np.ndarray) -> None:
        """Hand the episodes that ended in worlds ``ids`` (n,) to the curriculum (before their
        reset draws tiles from the new levels): one copy of their rows to the host."""
        rows = torch.as_tensor(ids, device=self.device)
        ended = self.ended[rows]
        stats = torch.cat([ended[:, None].to(_F32), self.ended_stats[rows]], dim=1).cpu().numpy()
        self.ended[rows] = False
        which = stats[:, 0] > 0
        if which.any():
            progress, expected, success = stats[which, 1], stats[which, 2], stats[which, 3] > 0
            self.env.curriculum.update(np.asarray(ids)[which], progress.astype(np.float64),
                                       expected.astype(np.float64), success, self.env.rng)

    # ------------------------------------------------------------------ state
    def read_state(self, rows: torch.Tensor | None = None) -> dict:
        """The body state of every world (or of worlds ``rows``), as the host
        :class:`~legoh_rl.envs.body_state.BodyStateReader` reads it (same keys and shapes), in
        float32 tensors on the device, plus ``gait_phase`` (n,) float64 or None."""
        v = self.worlds.views
        sel = slice(None) if rows is None else rows
        qpos, qvel = v["qpos"][sel], v["qvel"][sel]
        pos = qpos[:, 0:3]
        rot = quat_to_rotmat(qpos[:, 3:7])
        gravity_b = -rot[:, 2, :]
        roll, pitch = roll_pitch_from_gravity(gravity_b)
        lin_vel_w = qvel[:, 0:3]
        sd = v["sensordata"][sel]
        foot_force, pen_force = sd[:, self.foot_cols], sd[:, self.pen_cols]
        contact = (foot_force * foot_force).sum(-1) > CONTACT_FORCE_THRESHOLD**2
        feet_pos = v["xpos"][sel][:, self.foot_bodies]
        feet_xy = feet_pos[..., :2]
        heights = self.terrain.heights(torch.cat([pos[:, None, :2], feet_xy], dim=1))  # base, then feet
        goal_vec = self.end[sel, :2] - pos[:, :2]
        phase = self.gait_phase()
        return {
            "pos": pos, "rot": rot, "gravity_b": gravity_b, "roll": roll, "pitch": pitch,
            "yaw": torch.atan2(rot[:, 1, 0], rot[:, 0, 0]),
            "lin_vel_w": lin_vel_w, "lin_vel_b": (lin_vel_w[:, None, :] @ rot)[:, 0], "ang_vel_b": qvel[:, 3:6],
            "q": qpos[:, self.qpos_adr], "dq": qvel[:, self.dof_adr],
            "torques": v["actuator_force"][sel][:, self.act_ids],
            "foot_force": foot_force, "pen_force": pen_force, "contact": contact,
            "foot_on_edge": self.terrain.edge(feet_xy) & contact, "base_height": pos[:, 2] - heights[:, 0],
            "goal_vec": goal_vec, "goal_dist": torch.linalg.vector_norm(goal_vec, dim=1),
            "feet_xy": feet_xy, "foot_lift": feet_pos[..., 2] - heights[:, 1:] - self.env.body.foot_rest_height,
            "gait_phase": None if phase is None else phase[sel],
        }

    def gait_phase(self) -> torch.Tensor | None:
        """(N,) phase in [0, 1) of each world's gait clock, or None without a clock (float64 by
        default, computed as the host step does: the clock's stance thresholds then cut the same)."""
        period = self.env.cfg.gait_period
        if not period:
            return None
        return torch.remainder(self.episode_step.double() * self.env.dt / period, 1.0)

    def gait_reference(self, phase: torch.Tensor | None = None) -> torch.Tensor | None:
        """(N, A) leg-joint targets of the clock's swing reference at ``phase`` (default: now)."""
        env = self.env
        phase = self.gait_phase() if phase is None else phase
        if phase is None:
            return None
        offsets = swing_reference(phase, env.swing_joints, env.A, env.cfg.gait_amplitude)
        return (self.q_default64 if offsets.dtype == torch.float64 else self.q_default) + offsets

    # ------------------------------------------------------------------ the step
    def step(self, action: torch.Tensor) -> TensorDictBase:
        """One control step of every world from ``action`` (N, A) (checked by the env): the
        step's output tensordict, on the env's device."""
        env, cfg, worlds = self.env, self.env.cfg, self.worlds
        a = action.detach().to(self.device, _F32)
        finite = torch.isfinite(a).all(dim=1)
        bad_action = ~finite
        a = torch.where(finite[:, None], a, 0.0).clamp(-cfg.action_clip, cfg.action_clip)
        num_bad_action = bad_action.sum()  # read after the physics' wait, when it is computed
        self.action_prev.copy_(self.action)
        self.action.copy_(a)
        self.action_hist.copy_(torch.roll(self.action_hist, 1, dims=1))  # newest first
        self.action_hist[:, 0] = a
        delay = env.randomizer.delay_steps(env.global_steps)
        applied = self.action_hist[:, min(delay, self.action_hist.shape[1] - 1)]
        # the PD targets in float64, as the host step computes them, rounded once to the simulation's float32
        targets = self.q_default64 + env.robot.action_scale * applied.double()
        if cfg.gait_feedforward:
            phase = self.gait_phase()
            targets = targets + cfg.gait_feedforward * (self.gait_reference(phase) - self.q_default64)
        worlds.set_joint_targets(targets)

        env.episode_step += 1  # the host's copy of the clock (pushes, ticks)
        self.episode_step += 1
        env.global_steps += 1
        env.randomizer.push(env.episode_step % env.push_every == 0, env.rng)
        physics = time.perf_counter()
        diverged = worlds.step()  # (waits for the device: its divergence count)
        env.time_spent["physics"] += time.perf_counter() - physics
        bad_actions = int(num_bad_action)
        if bad_actions:
            env.bad_action_total += bad_actions
        if worlds.diverged_total != env.diverged_total:
            env.diverged_total = worlds.diverged_total

        state, total, terms, episode, flags = self._score_step(diverged)
        np.equal(env.episode_step % cfg.perception_every, 0, out=env.tick)
        self.tick.copy_(self.episode_step % cfg.perception_every == 0)
        env._render_depth(env.tick)
        self.send_depth(env.tick)
        obs = self._observations(state)
        self._obs.update(obs)
        return self.to_td(obs, episode, info=(diverged, bad_action), flags=flags, reward=total, reward_terms=terms)

    def _episodes_ended(self, done: torch.Tensor, progress: torch.Tensor, expected: torch.Tensor,
                        success: torch.Tensor) -> None:
        """Keep the progress of the episodes that end where ``done`` for :meth:`settle_curriculum`
        (no copy to the host here: the curriculum learns of them when their worlds reset)."""
        stats = torch.stack([progress, expected, success.to(_F32)], dim=1)
        self.ended_stats.copy_(torch.where(done[:, None], stats, self.ended_stats))
        self.ended |= done

    def _pit_under(self, feet_xy: torch.Tensor) -> torch.Tensor:
        return self.terrain.pit(feet_xy)

    # ------------------------------------------------------------------ observations
    def _scandots(self, pos: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
        ground = pos[:, 2:3] - self.env.robot.base_height_target
        return (self.terrain.heights(yaw_frame_points(pos[:, :2], yaw, self.scandot_xy)) - ground).clamp(-1.0, 1.0)

    def _privileged_dr(self) -> torch.Tensor:
        return self.privileged_dr

    def _depth_rows(self, sel) -> torch.Tensor | None:
        if self.env.depth is None:
            return None
        return (self.env.depth if self.depth is None else self.depth)[sel]

    def send_depth(self, which: np.ndarray) -> None:
        """Copy the host-marched depth rows of worlds ``which`` (N,) bool to the device (nothing
        to do when the camera casts on the device, or has none)."""
        if self.depth is None or not which.any():
            return
        ids = np.flatnonzero(which)
        if ids.size == which.size:
            self.depth.copy_(torch.from_numpy(self.env.depth))
        else:
            self.depth[torch.as_tensor(ids, device=self.device)] = torch.from_numpy(self.env.depth[ids]).to(self.device)

    def to_td(self, obs: dict, episode: dict, info: tuple, flags: tuple, reward: torch.Tensor | None = None,
              reward_terms: dict | None = None) -> TensorDictBase:
        """The step/reset output (as the host step's ``_to_td``), every value a fresh (N, ...)
        tensor moved to the env's device (already there when the simulation's device is the env's)."""
        dev = self.env.device

        def col(x: torch.Tensor, dtype=_F32) -> torch.Tensor:
            return x.to(dtype)[:, None].to(dev)

        out: dict = {k: (v.to(_F32) if k != "perception_tick" else v).clone().to(dev) for k, v in obs.items()}
        out["episode"] = {k: col(episode[k]) for k in METRIC_NAMES}
        out["episode"]["level"] = col(episode["level"], torch.int64)
        out["episode"]["category"] = col(episode["category"], torch.int64)
        out["info"] = {"diverged": col(info[0], torch.bool), "bad_action": col(info[1], torch.bool)}
        out["done"], out["terminated"], out["truncated"] = (col(f, torch.bool) for f in flags)
        if reward is not None:
            out["reward"] = col(reward)
            out["reward_terms"] = {k: col(v) for k, v in reward_terms.items()}
        return TensorDict._new_unsafe(out, batch_size=self.env.batch_size, device=dev)

    def host_state(self, ids: np.ndarray | None = None) -> dict:
        """:meth:`read_state` of worlds ``ids`` (all if None) as float64 numpy arrays (bool for
        the contact flags), for the env's :meth:`~legoh_rl.envs.hiking.HikingEnv.read_state`."""
        rows = None if ids is None else torch.as_tensor(np.asarray(ids, dtype=np.int64), device=self.device)
        out = {}
        for key, value in self.read_state(rows).items():
            if value is None:
                out[key] = None
                continue
            value = value.cpu().numpy()
            out[key] = value if value.dtype == bool else value.astype(np.float64)
        return out
