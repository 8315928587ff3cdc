"""What a hiking step derives from the body state, written once for numpy and torch.

After the physics, a step of :class:`~legoh_rl.envs.hiking.HikingEnv` moves the expert goals on,
assembles the reward terms' inputs, decides the episode ends, scores the ended episodes and builds
the observations. The host step does this on float64 numpy arrays; the device-resident step
(``HikingEnvConfig.resident``, docs/gpu_physics.md) on float32 torch tensors on the simulation's
device. :class:`StepQuantities` holds the one definition of each, against the array API
(:mod:`legoh_rl.envs.array_api`), for both: :class:`~legoh_rl.envs.step_state.StepState`, which
keeps the per-world state as numpy arrays or as tensors, inherits it (the tests also drive it
from hand-made states).

The per-world state a subclass keeps (N worlds, A actions, G goals slots; arrays of one kind):

* ``goals`` (N, G, 3) expert goals then P_B, ``num_goals`` (N,), ``goal_idx`` (N,) int, and
  ``goal_offsets`` (k,) ``arange(num_goals)`` of the observed goals, ``world_index`` (N,)
  ``arange(N)``;
* ``start``/``end``/``waypoint`` (N, 3), ``tile`` (N,) and the per-tile ``tile_level``/
  ``tile_category`` (T,);
* ``_obs``, a dict of the last observations (updated in place by partial resets);
* ``action``/``action_prev``/``dq_prev``/``torques_prev`` (N, A), ``feet_air_time`` (N, 2),
  ``last_contact`` (N, 2) bool, ``feet_xy_prev`` (N, 2, 2), ``episode_step`` (N,) int, ``tick``
  (N,) bool, ``metrics`` (:class:`~legoh_rl.envs.metrics.EpisodeMetrics`);
* constants ``q_default`` (A,), ``q_soft_limits`` (A, 2), ``hip_idx`` (H,) and ``scandot_xy`` (K, 2);
  ``foot_scan_xy``, the foot scan's blocks of points, each (K_b, 2) (empty without ``cfg.foot_scan``);
* ``cfg``, ``dt``, ``robot``, ``weights``, ``max_steps`` (the env's);

and the lookups that differ by where the terrain and the camera live (:class:`StepQuantities`
lists them).
"""

from __future__ import annotations

import math

import numpy as np

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.config import ANG_VEL_SCALE, DOF_VEL_SCALE, LIN_VEL_SCALE
from legoh_rl.envs.metrics import METRIC_NAMES
from legoh_rl.envs.rewards import RewardState, compute_rewards
from legoh_rl.envs.sensors import world_to_yaw_frame

__all__ = ["StepQuantities"]


class StepQuantities:
    """The goal tracking, reward inputs, episode ends, episode scores and observations of a step,
    on numpy arrays (the host step) or torch tensors (the device-resident step).

    A subclass keeps the state the module docstring lists and defines the lookups:

    * ``_scandots(pos, yaw)``: (N, K) terrain heights around bases at ``pos`` (N, 3) with headings
      ``yaw`` (N,), relative to the nominal ground, clipped to [-1, 1];
    * ``_foot_scan(sel)``: (n, sum of 2 K_b) terrain heights around the feet of worlds ``sel`` (a
      slice or (n,) indices), relative to their soles, clipped to [-1, 1], block by block (both
      feet of a block, then the next; read with ``cfg.foot_scan``);
    * ``_pit_under(feet_xy)``: (N, 2) bool, each foot at ``feet_xy`` (N, 2, 2) over a pit;
    * ``_privileged_dr()``: (N, 5 + A) the randomised dynamics of the privileged observation;
    * ``_depth_rows(sel)``: the depth images of worlds ``sel`` (a slice or (n,) indices), or None;
    * ``_episodes_ended(done, progress, expected, success)``: hand the episodes where ``done``
      (N,) bool, with their (N,) progress and expected progress (m) and success, to the curriculum;
    * ``gait_reference(phase)``: (N, A) joint targets of the gait clock's swing reference.
    """

    # ------------------------------------------------------------------ goals
    def _advance_goals(self, pos) -> None:
        """Move each world's current expert goal on once the base at ``pos`` (N, 3) is within
        ``goal_reach_radius`` of it or has passed it along the next leg; counts the goals reached."""
        xp = namespace_of(pos)
        n, idx = self.world_index, self.goal_idx
        last = self.num_goals - 1
        cur = self.goals[n, idx, :2]
        nxt = self.goals[n, xp.minimum(idx + 1, last), :2]
        to_cur = cur - pos[:, :2]
        reached = xp.sum(to_cur * to_cur, axis=1) < self.cfg.goal_reach_radius**2
        passed = xp.sum(-to_cur * (nxt - cur), axis=1) > 0.0  # beyond the goal, along the next leg
        before_last = idx < last
        self.metrics.goals_passed += xp.astype(reached & before_last, self.metrics.goals_passed.dtype)
        idx += xp.astype((reached | passed) & before_last, idx.dtype)

    def _goal_dirs(self, pos, rows=None):
        """Unit world-frame xy directions to the next ``num_goals`` expert goals, (N, k, 2), or
        (n, k, 2) for worlds ``rows`` (n,) with ``pos`` (n, 3) their positions."""
        xp = namespace_of(pos)
        n = (self.world_index if rows is None else rows)[:, None]
        idx = xp.minimum(self.goal_idx[n] + self.goal_offsets[None], self.num_goals[n] - 1)
        vec = self.goals[n, idx, :2] - pos[:, None, :2]
        return vec / xp.maximum(xp.sqrt(xp.sum(vec * vec, axis=-1))[..., None], 1e-6)

    # ------------------------------------------------------------------ rewards and episode ends
    def _reward_state(self, s: dict) -> RewardState:
        """The reward terms' inputs from the state ``s`` (``read_state`` with ``goal_dirs_w``);
        advances the feet's air-time clocks and keeps this step's contacts and foot positions."""
        xp = namespace_of(s["q"])
        cfg, dt = self.cfg, self.dt
        contact_filt = s["contact"] | self.last_contact
        first_contact = (self.feet_air_time > 0.0) & contact_filt
        air_clock = self.feet_air_time
        air_clock += dt
        air_time = xp.asarray(air_clock, copy=True)
        air_clock *= ~contact_filt
        self.last_contact[...] = s["contact"]
        foot_vel_xy = (s["feet_xy"] - self.feet_xy_prev) / dt
        self.feet_xy_prev[...] = s["feet_xy"]
        gait_ref = None
        if "gait_joint_ref" in self.weights:  # the swing reference only when a term reads it
            gait_ref = xp.astype(self.gait_reference(s["gait_phase"]), s["q"].dtype, copy=False)
        return RewardState(
            lin_vel_w=s["lin_vel_w"], ang_vel_b=s["ang_vel_b"], gravity_b=s["gravity_b"],
            goal_dir_w=s["goal_dirs_w"][:, 0], yaw=s["yaw"],
            cmd_speed=xp.full_like(s["yaw"], cfg.cmd_speed),
            q=s["q"], dq=s["dq"], dq_prev=self.dq_prev, q_default=self.q_default,
            q_limits=self.q_soft_limits, hip_idx=self.hip_idx,
            torques=s["torques"], torques_prev=self.torques_prev,
            action=self.action, action_prev=self.action_prev,
            foot_force=s["foot_force"], penalised_force=s["pen_force"],
            feet_air_time=air_time, first_contact=first_contact, feet_at_edge=s["foot_on_edge"],
            terrain_level=self.tile_level[self.tile], base_height=s["base_height"],
            base_height_target=self.robot.base_height_target, base_height_cap=cfg.base_height_error_cap,
            goal_dist=s["goal_dist"],
            reach_radius=cfg.reach_radius, dt=dt,
            feet_contact=s["contact"], foot_lift=s["foot_lift"], foot_vel_xy=foot_vel_xy,
            swing_height=cfg.swing_height, gait_phase=s["gait_phase"], gait_stance=cfg.gait_stance,
            gait_ref_q=gait_ref, feet_edge_from_level=cfg.feet_edge_from_level,
            feet_in_pit=self._pit_under(s["feet_xy"]) & s["contact"] if "feet_in_pit" in self.weights else None,
        )

    def _episode_ends(self, s: dict, diverged, held=None):
        """``(fell, success, terminated, truncated, done)``, each (N,) bool, from the state ``s``
        and the worlds whose physics ``diverged`` (N,) bool (truncated, neither fell nor succeeded);
        all False on the ``held`` (N,) bool worlds (None: none held)."""
        xp = namespace_of(s["roll"])
        cfg = self.cfg
        fell = ((xp.abs(s["roll"]) > cfg.fall_roll_pitch) | (xp.abs(s["pitch"]) > cfg.fall_roll_pitch)
                | (s["base_height"] < cfg.fall_height_ratio * self.robot.base_height_target)) & ~diverged
        success = (s["goal_dist"] < cfg.reach_radius) & ~diverged & ~fell
        truncated = (self.episode_step >= self.max_steps) | diverged
        if held is not None:
            fell, success, truncated = fell & ~held, success & ~held, truncated & ~held
        terminated = fell | success
        truncated = truncated & ~terminated
        return fell, success, terminated, truncated, terminated | truncated

    def _finish_episodes(self, done, success, s: dict) -> dict:
        """The six metrics of the episodes that end where ``done`` (N,) (0, or NaN for
        ``time_to_reach``, elsewhere) with each world's ``level`` and ``category``; hands the ended
        episodes' progress to :meth:`_episodes_ended`."""
        xp = namespace_of(s["goal_dist"])
        cfg, dist = self.cfg, s["goal_dist"]
        leg = self.end[:, :2] - self.start[:, :2]
        trail_len = xp.sqrt(xp.sum(leg * leg, axis=1))
        ep_time = xp.astype(self.episode_step, dist.dtype) * self.dt
        metrics = self.metrics.finish(success, ep_time, dist, trail_len, self.num_goals - 1)
        episode = {name: xp.where(done, metrics[name], 0.0) for name in METRIC_NAMES}
        episode["time_to_reach"] = xp.where(done, metrics["time_to_reach"], float("nan"))
        episode["level"], episode["category"] = self.tile_level[self.tile], self.tile_category[self.tile]
        progress = xp.maximum(trail_len - dist, 0.0)
        expected = xp.minimum(trail_len, cfg.cmd_speed * cfg.max_episode_s)
        self._episodes_ended(done, progress, expected, success)
        return episode

    def _empty_episode(self) -> dict:
        """:meth:`_finish_episodes`' output where no episode ends."""
        xp = namespace_of(self.metrics.contact_samples)
        zeros = xp.zeros_like(self.metrics.contact_samples)
        ep = {name: zeros + (float("nan") if name == "time_to_reach" else 0.0) for name in METRIC_NAMES}
        ep["level"], ep["category"] = self.tile_level[self.tile], self.tile_category[self.tile]
        return ep

    # ------------------------------------------------------------------ the step after the physics
    def world_weights(self) -> dict:
        """The reward weights of this step: ``self.weights``, with each term that
        ``category_reward_scales`` names as an (N,) array, its weight times the scale of every
        world's current trail category."""
        if not self.category_scales:
            return self.weights
        category = self.tile_category[self.tile]  # (N,)
        return {name: w * self.category_scales[name][category] if name in self.category_scales else w
                for name, w in self.weights.items()}

    def _score_step(self, diverged, held=None):
        """Everything a step derives from the new physical state but the observations: reads the
        state, moves the goals on, computes the reward and its terms, decides and scores the
        episode ends and keeps this step's joint velocities and torques for the next one.

        Args:
            diverged: (N,) bool, the worlds whose physics diverged (and were reset) this step.
            held: (N,) bool, worlds held still (:meth:`~legoh_rl.envs.hiking.HikingEnv.hold`):
                none of their episodes ends; None: no world is held.

        Returns:
            ``(state, reward, terms, episode, flags)``: the state (``read_state`` with
            ``goal_dirs_w``), the (N,) reward, its weighted terms by name, the episode metrics
            (:meth:`_finish_episodes`), and ``(done, terminated, truncated)``, each (N,) bool.
        """
        state = self.read_state()
        self._advance_goals(state["pos"])
        state["goal_dirs_w"] = self._goal_dirs(state["pos"])
        fell, success, terminated, truncated, done = self._episode_ends(state, diverged, held)
        reward_state = self._reward_state(state)
        reward_state.fell = fell
        total, terms = compute_rewards(reward_state, self.world_weights(), self.cfg.only_positive_rewards)
        self.metrics.record_step(state["contact"], state["foot_on_edge"])
        if isinstance(done, np.ndarray) and not done.any():  # (a device's flags are not read back to skip it)
            episode = self._empty_episode()
        else:
            episode = self._finish_episodes(done, success, state)
        self.dq_prev[...] = state["dq"]
        self.torques_prev[...] = state["torques"]
        return state, total, terms, episode, (done, terminated, truncated)

    # ------------------------------------------------------------------ observations
    def _observations(self, s: dict, rows=None) -> dict:
        """Observation arrays of every world from ``s`` (``read_state`` with ``goal_dirs_w``), or
        of worlds ``rows`` (n,) from their rows ``s = read_state(rows)``: ``proprio``, ``goal_gps``,
        ``waypoint_gps``, ``scandots``, ``privileged``, ``expert_goals``, ``perception_tick`` and
        ``depth`` with a camera (docs/observations.md has the layouts)."""
        xp = namespace_of(s["q"])
        sel = slice(None) if rows is None else rows
        yaw, phase, dtype = s["yaw"], s["gait_phase"], s["q"].dtype
        clock = []
        if phase is not None:
            angle = 2.0 * math.pi * phase
            clock = [xp.astype(xp.stack([xp.sin(angle), xp.cos(angle)], axis=1), dtype, copy=False)]
        proprio = xp.concat([s["ang_vel_b"] * ANG_VEL_SCALE, s["roll"][:, None], s["pitch"][:, None],
                             s["q"] - self.q_default, s["dq"] * DOF_VEL_SCALE, self.action[sel],
                             xp.astype(s["contact"], dtype), *clock], axis=1)
        # goal, waypoint and expert-goal directions rotated together: (N, 2 + k, 2)
        vecs = world_to_yaw_frame(xp.concat([s["goal_vec"][:, None], (self.waypoint[sel, :2] - s["pos"][:, :2])[:, None],
                                             s["goal_dirs_w"]], axis=1), yaw)
        scan = self._scandots(s["pos"], yaw)
        if self.cfg.foot_scan:  # the feet's own scan after the base's scandots
            scan = xp.concat([xp.astype(scan, dtype, copy=False), xp.astype(self._foot_scan(sel), dtype, copy=False)],
                             axis=1)
        obs = {
            "proprio": proprio,
            "goal_gps": vecs[:, 0],
            "waypoint_gps": vecs[:, 1],
            "scandots": scan,
            "privileged": xp.concat([s["lin_vel_b"] * LIN_VEL_SCALE, self._privileged_dr()[sel]], axis=1),
            "expert_goals": vecs[:, 2:],
            "perception_tick": self.tick[sel, None],
        }
        depth = self._depth_rows(sel)
        if depth is not None:
            obs["depth"] = depth
        return obs

    def _refresh_observations(self, rows) -> dict:
        """The observations after worlds ``rows`` (n,) (indices of the state's kind) were reset:
        every world's on the first call or when all were reset, else the last step's with those
        rows refreshed. Kept in ``_obs`` (the arrays are updated in place)."""
        if not self._obs or rows.shape[0] == self.world_index.shape[0]:
            state = self.read_state()
            state["goal_dirs_w"] = self._goal_dirs(state["pos"])
            self._obs.update(self._observations(state))
            return self._obs
        state = self.read_state(rows)
        state["goal_dirs_w"] = self._goal_dirs(state["pos"], rows)
        for key, value in self._observations(state, rows).items():
            self._obs[key][rows] = value
        return self._obs
