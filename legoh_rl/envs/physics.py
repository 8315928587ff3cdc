"""N MuJoCo worlds of one model stepped together in C threads (``mujoco.batch.Batch``).

:class:`BatchedWorlds` is the only place the env touches MuJoCo's state (or
:class:`~legoh_rl.envs.warp_physics.WarpWorlds`, the same contract on MuJoCo Warp; both derive
from :class:`Worlds`, which holds what does not depend on the physics engine). Everything is an
``(N, ...)`` numpy array; no method loops over worlds in Python.

* ``set_joint_targets`` writes the PD targets q* of all worlds (the position actuators' ctrl);
* ``step`` advances ``decimation`` physics substeps, then computes positions and velocities at
  the new state (``mjSTAGE_VEL``; the batch is persistent, so this costs nothing extra);
* ``reset`` puts any subset of worlds into given states;
* per-world model parameters (friction, masses, CoM, actuator strength) for domain
  randomisation through ``Batch.expand``;
* divergence: a world whose state goes non-finite or beyond sane bounds, or whose MuJoCo
  instability warnings rise (MuJoCo then silently resets that world to ``qpos0``), or whose step
  raised, is reset to its *home* state (the state of its last reset) and counted. The others
  continue untouched.
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod

import mujoco
import mujoco.batch as mjb
import numpy as np

from legoh_rl.envs.robots import BuiltModel

__all__ = ["Worlds", "BatchedWorlds", "default_num_threads", "MAX_ABS_QVEL"]

_INSTABILITY_WARNINGS = (
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
)
# |qvel| beyond this (m/s or rad/s) is treated as a diverged world even if still finite.
MAX_ABS_QVEL = 1.0e3


def default_num_threads() -> int:
    """Physics threads by default: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


class Worlds(ABC):
    """What every physics backend of the env shares: arguments, home states, PD targets, world ids.

    A backend calls :meth:`_init_common`, sets the live ``(N, ...)`` float64 arrays ``qpos``,
    ``qvel``, ``ctrl``, ``xpos``, ``xquat``, ``sensordata``, ``actuator_force``, ``cam_xpos``,
    ``cam_xmat``, and implements the abstract methods below.
    """

    def _init_common(self, built: BuiltModel, num_worlds: int, decimation: int, num_threads: int | None) -> None:
        if not isinstance(num_worlds, (int, np.integer)) or num_worlds < 1:
            raise ValueError(f"num_worlds must be a positive integer, got {num_worlds!r}")
        if not isinstance(decimation, (int, np.integer)) or decimation < 1:
            raise ValueError(f"decimation must be a positive integer, got {decimation!r}")
        nthread = default_num_threads() if num_threads is None else int(num_threads)
        if nthread < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads!r}")
        self.built = built
        self.model = built.model
        self.num_worlds = int(num_worlds)
        self.decimation = int(decimation)
        self.num_threads = nthread
        self.diverged_total = 0
        self.home_qpos = np.tile(built.default_qpos, (self.num_worlds, 1))
        self.home_qvel = np.zeros((self.num_worlds, self.model.nv))
        self._nominal: dict[str, np.ndarray] = {}

    @property
    def dt(self) -> float:
        """Control period: timestep x decimation, s."""
        return float(self.model.opt.timestep) * self.decimation

    def reset(
        self,
        ids: np.ndarray | None = None,
        qpos: np.ndarray | None = None,
        qvel: np.ndarray | None = None,
    ) -> None:
        """Put worlds ``ids`` into the given states; the others are untouched.

        Args:
            ids: world indices (n,) or a bool mask (N,); ``None`` = all.
            qpos: their positions (n, nq); ``None`` = the robot's default standing pose at the
                origin.
            qvel: their velocities (n, nv); ``None`` = zero.

        The given state becomes each world's home state (where it returns if it diverges) and the
        PD targets are set to the default joint pose.
        """
        idx = self._ids(ids)
        if idx.size == 0:
            return
        n = idx.size
        qpos = np.tile(self.built.default_qpos, (n, 1)) if qpos is None else np.asarray(qpos, float)
        qvel = np.zeros((n, self.model.nv)) if qvel is None else np.asarray(qvel, float)
        if qpos.shape != (n, self.model.nq):
            raise ValueError(f"qpos must have shape {(n, self.model.nq)}, got {qpos.shape}")
        if qvel.shape != (n, self.model.nv):
            raise ValueError(f"qvel must have shape {(n, self.model.nv)}, got {qvel.shape}")
        if not (np.isfinite(qpos).all() and np.isfinite(qvel).all()):
            raise ValueError("reset states must be finite")
        self.home_qpos[idx] = qpos
        self.home_qvel[idx] = qvel
        self._reset_to_home(idx)

    @abstractmethod
    def _reset_to_home(self, idx: np.ndarray) -> None:
        """Put worlds ``idx`` (n,) back into their home states, PD targets at the default pose,
        their outputs computed."""

    @abstractmethod
    def step(self, active: np.ndarray | None = None) -> np.ndarray:
        """Advance the worlds ``decimation`` substeps; returns (N,) bool, the worlds that
        diverged and were reset to their home states (counted in ``diverged_total``).

        ``active`` (N,) bool names the worlds that need advancing (None: all); a backend may
        leave the others where they are (the C MuJoCo batch does) or step them too."""

    @abstractmethod
    def per_world(self, field: str) -> np.ndarray:
        """A per-world ``(N, ...)`` copy of a model field that domain randomisation writes into."""

    @abstractmethod
    def set_const(self, ids: np.ndarray | None = None) -> None:
        """Recompute the constants derived from masses and inertias (worlds ``ids``, all if None)."""

    @abstractmethod
    def world_data(self, world: int, data: mujoco.MjData) -> None:
        """Copy world ``world``'s state, with its positions computed, into ``data`` (for a renderer)."""

    @property
    def default_targets(self) -> np.ndarray:
        """PD targets of the default pose in ctrl order, (nu,)."""
        targets = np.zeros(self.model.nu)
        targets[self.built.actuator_ids] = self.built.robot.default_joint_pos
        return targets

    def set_joint_targets(self, q_target: np.ndarray) -> None:
        """Set PD joint targets q* of every world, (N, A) rad in leg-joint order."""
        q_target = np.asarray(q_target)
        expected = (self.num_worlds, self.built.actuator_ids.size)
        if q_target.shape != expected:
            raise ValueError(f"joint targets must have shape {expected}, got {q_target.shape}")
        self.ctrl[:, self.built.actuator_ids] = q_target

    def set_base_xy_velocity(self, ids: np.ndarray, velocity: np.ndarray) -> None:
        """Set the base's world xy velocity of worlds ``ids`` (n,) to ``velocity`` (n, 2) m/s (a push)."""
        self.qvel[ids, 0:2] = velocity

    def refresh_host(self, rows: np.ndarray | None = None) -> None:
        """Make the host arrays of worlds ``rows`` current (they always are here; a device-resident
        backend copies them on request)."""
        return None

    def nominal(self, field: str) -> np.ndarray:
        """The model's value of ``field`` before any per-world change."""
        if field not in self._nominal:
            self._nominal[field] = np.array(getattr(self.model, field), copy=True)
        return self._nominal[field]

    def unstable_rows(self) -> np.ndarray:
        """(N,) bool: worlds whose state is non-finite or whose speed exceeds ``MAX_ABS_QVEL``
        (one reduction per array in the usual case, rows only otherwise)."""
        if np.isfinite(self.qpos.sum()) and np.abs(self.qvel).max() <= MAX_ABS_QVEL:
            return np.zeros(self.num_worlds, dtype=bool)
        return (~np.isfinite(self.qpos).all(axis=1) | ~np.isfinite(self.qvel).all(axis=1)
                | (np.abs(self.qvel).max(axis=1) > MAX_ABS_QVEL))

    def _ids(self, ids: np.ndarray | None) -> np.ndarray:
        if ids is None:
            return np.arange(self.num_worlds)
        ids = np.asarray(ids)
        if ids.dtype == bool:
            if ids.shape != (self.num_worlds,):
                raise ValueError(f"world mask must have shape ({self.num_worlds},), got {ids.shape}")
            return np.flatnonzero(ids)
        ids = ids.astype(np.int64).reshape(-1)
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_worlds):
            raise ValueError(f"world ids must lie in [0, {self.num_worlds}), got {ids}")
        return ids


class BatchedWorlds(Worlds):
    """``num_worlds`` copies of a :class:`BuiltModel`, stepped in parallel.

    Args:
        built: the compiled robot + terrain model.
        num_worlds: N, number of worlds (>= 1).
        decimation: physics substeps per control step (>= 1).
        num_threads: C threads stepping the worlds; ``None`` = all usable CPUs.

    Live state arrays (writes go to the simulation): ``qpos`` (N, nq), ``qvel`` (N, nv),
    ``ctrl`` (N, nu). Read-only outputs refreshed after every call: ``xpos`` (N, nbody, 3),
    ``xquat`` (N, nbody, 4), ``sensordata`` (N, nsensordata), ``actuator_force`` (N, nu),
    ``cam_xpos`` (N, ncam, 3), ``cam_xmat`` (N, ncam, 9).

    Attributes:
        diverged_total: worlds reset because they diverged, since construction.
    """

    def __init__(
        self,
        built: BuiltModel,
        num_worlds: int,
        decimation: int = 4,
        num_threads: int | None = None,
    ) -> None:
        self._init_common(built, num_worlds, decimation, num_threads)
        self.batch = mjb.Batch(self.model, self.num_worlds, self.num_threads, persistent=True)
        b = self.batch
        self.qpos = b.bind("qpos")
        self.qvel = b.bind("qvel")
        self.ctrl = b.bind("ctrl")
        self.xpos = b.bind("xpos")
        self.xquat = b.bind("xquat")
        self.sensordata = b.bind("sensordata")
        self.actuator_force = b.bind("actuator_force")
        self.cam_xpos = b.bind("cam_xpos")
        self.cam_xmat = b.bind("cam_xmat")
        self._warn_seen = np.zeros((self.num_worlds,), dtype=np.int64)
        self.reset()

    # ------------------------------------------------------------------ state
    @property
    def time(self) -> np.ndarray:
        """Simulation time of each world, (N,) s."""
        return self.batch.bind("time")

    def _instability_count(self) -> np.ndarray:
        # Batch.warning is (N, mjNWARNING, 2) of mjWarningStat = (lastinfo, number).
        return self.batch.warning[:, list(_INSTABILITY_WARNINGS), 1].sum(axis=1).astype(np.int64)

    def _reset_to_home(self, idx: np.ndarray) -> None:
        b = self.batch
        b.reset(idx, stage=mujoco.mjtStage.mjSTAGE_NONE)
        self.qpos[idx] = self.home_qpos[idx]
        self.qvel[idx] = self.home_qvel[idx]
        self.ctrl[idx] = self.default_targets
        b.forward(idx, stage=mujoco.mjtStage.mjSTAGE_ACC)
        self._warn_seen[idx] = self._instability_count()[idx]

    def step(self, active: np.ndarray | None = None) -> np.ndarray:
        """Advance the worlds ``decimation`` substeps; reset and count the ones that diverged.

        Args:
            active: (N,) bool, the worlds to advance; the others keep their state exactly (an
                evaluation's finished worlds, :meth:`~legoh_rl.envs.hiking.HikingEnv.hold`).
                None: every world.

        Returns:
            diverged: (N,) bool, worlds that diverged during this step and were reset to their
            home state.
        """
        failed = np.zeros(self.num_worlds, dtype=bool)
        ids = None
        if active is not None:
            active = np.asarray(active, dtype=bool)
            if active.shape != (self.num_worlds,):
                raise ValueError(f"active must be a ({self.num_worlds},) bool mask, got shape {active.shape}")
            if not active.all():
                ids = np.flatnonzero(active)
                if ids.size == 0:
                    return failed
        try:
            self.batch.step(ids, nstep=self.decimation, stage=mujoco.mjtStage.mjSTAGE_VEL)
        except mjb.SimulationError as err:  # those worlds kept their pre-step state
            failed[np.asarray(err.ids, dtype=np.int64)] = True
        warn = self._instability_count()
        bad = failed | (warn > self._warn_seen)
        self._warn_seen = warn
        bad |= self.unstable_rows()
        if bad.any():
            idx = np.flatnonzero(bad)
            self.diverged_total += int(idx.size)
            self._reset_to_home(idx)
        return bad

    # ------------------------------------------------------------------ model parameters
    def per_world(self, field: str) -> np.ndarray:
        """Live per-world copy of a model field, (N, ...), for domain randomisation.

        The nominal (shared) value is remembered the first time, see :meth:`nominal`.
        """
        self.nominal(field)
        return self.batch.expand(field)

    def set_const(self, ids: np.ndarray | None = None) -> None:
        """Recompute derived constants of worlds ``ids`` (all if None) after changing masses
        or inertias (mj_setConst)."""
        self.batch.set_const(None if ids is None else self._ids(ids).astype(np.int32))

    def world_data(self, world: int, data: mujoco.MjData) -> None:
        """Copy world ``world``'s state (and what the last step computed) into ``data`` (for a
        renderer)."""
        self.batch.get_data(int(world), data)
