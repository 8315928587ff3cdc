"""Domain randomisation with the paper's ranges, per world, through per-world model fields.

Nothing is rebuilt: each randomised quantity lives in a field that ``Batch.expand`` made
per-world (friction, base mass, base CoM, actuator gains), or in the env's own arrays (pushes,
action delay). Every term can be switched off and all draws come from the env's seeded
generator.

| term | paper range | how |
|---|---|---|
| friction | U(0.6, 2.0) | sliding friction of every robot geom (robot geoms have contact priority, so the contact uses it) |
| base mass offset | U(0, 3) kg | added to the pelvis mass (then ``mj_setConst``) |
| base CoM offset | U(-0.2, 0.2) m per axis | added to the pelvis inertial frame position |
| motor strength | U(0.8, 1.2) per joint | scales kp and kd of each leg actuator (its torque) |
| push | every 8 s, up to 0.5 m/s | base xy velocity set to U(-0.5, 0.5) m/s per axis |
| action delay | after 24 x 8000 global steps | the action applied lags by ``delay_steps`` control steps |
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from legoh_rl.kinds import Flag, Integer, ListOf, Number, check_fields, setting

__all__ = ["DOMAIN_RAND_TERMS", "DomainRandConfig", "DomainRandomizer"]

#: the switches of :class:`DomainRandConfig`, one per row of the table above
DOMAIN_RAND_TERMS = ("friction", "base_mass", "base_com", "motor_strength", "push", "action_delay")
_RANGE = ListOf(Number(), length=2)  # (low, high)


@dataclass
class DomainRandConfig:
    """Switches and ranges (defaults: the paper's table); ``enabled``: the master switch (false:
    every term off, whatever its own switch says; the nominal robot)."""

    enabled: bool = setting(True, Flag())
    friction: bool = setting(True, Flag())
    friction_range: tuple[float, float] = setting((0.6, 2.0), _RANGE)
    base_mass: bool = setting(True, Flag())
    base_mass_range: tuple[float, float] = setting((0.0, 3.0), _RANGE)
    base_com: bool = setting(True, Flag())
    base_com_range: tuple[float, float] = setting((-0.2, 0.2), _RANGE)
    motor_strength: bool = setting(True, Flag())
    motor_strength_range: tuple[float, float] = setting((0.8, 1.2), _RANGE)
    push: bool = setting(True, Flag())
    push_interval_s: float = setting(8.0, Number(0, low_open=True))
    push_max_vel_xy: float = setting(0.5, Number(0))
    action_delay: bool = setting(True, Flag())
    #: env steps per world after which the action delay starts (the paper's 24 x 8000; 0: at once)
    delay_after_global_steps: int = setting(24 * 8000, Integer(0))
    delay_steps: int = setting(1, Integer(0))

    @classmethod
    def off(cls) -> DomainRandConfig:
        """Every term's switch off (nominal robot). The master switch stays on, so that
        ``dataclasses.replace(DomainRandConfig.off(), push=True)`` randomises pushes alone."""
        return cls(**{term: False for term in DOMAIN_RAND_TERMS})

    def only(self, terms: Iterable[str]) -> DomainRandConfig:
        """This config with the terms of :data:`DOMAIN_RAND_TERMS` named in ``terms`` on and the
        others off, ranges kept (ValueError naming an unknown term)."""
        terms = list(terms)
        bad = [t for t in terms if t not in DOMAIN_RAND_TERMS]
        if bad:
            raise ValueError(f"unknown domain randomisation term(s) {bad}; valid: {list(DOMAIN_RAND_TERMS)}")
        return replace(self, enabled=True, **{t: t in terms for t in DOMAIN_RAND_TERMS})

    def __post_init__(self) -> None:
        check_fields(self)  # each field against its kind (legoh_rl/kinds.py)
        for name in ("friction_range", "base_mass_range", "base_com_range", "motor_strength_range"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        if not self.enabled:
            for term in DOMAIN_RAND_TERMS:
                setattr(self, term, False)


class DomainRandomizer:
    """Draws and applies per-world physical parameters.

    Args:
        cfg: the switches and ranges.
        worlds: the :class:`~legoh_rl.envs.physics.BatchedWorlds`.

    Attributes (all (N, ...) arrays, the values in force, nominal when a term is off):
        friction (N,), mass_offset (N,), com_offset (N, 3), motor_strength (N, A).
    """

    def __init__(self, cfg: DomainRandConfig, worlds) -> None:
        self.cfg = cfg
        self.worlds = worlds
        built = worlds.built
        n, a = worlds.num_worlds, built.actuator_ids.size
        self._robot_geoms = built.robot_geom_ids[worlds.model.geom_contype[built.robot_geom_ids] != 0]
        self._base = built.base_body_id
        self._acts = built.actuator_ids
        self.friction = np.ones(n)
        self.mass_offset = np.zeros(n)
        self.com_offset = np.zeros((n, 3))
        self.motor_strength = np.ones((n, a))
        self.nominal_friction = float(worlds.model.geom_friction[self._robot_geoms, 0].mean())
        self.friction[:] = self.nominal_friction

    def privileged(self) -> np.ndarray:
        """(N, 5 + A): friction, mass offset, CoM offset (3), motor strength (A)."""
        return np.concatenate(
            [self.friction[:, None], self.mass_offset[:, None], self.com_offset, self.motor_strength], axis=1
        )

    def randomize(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Draw new parameters for worlds ``ids`` (n,) and write them into their models."""
        cfg, w = self.cfg, self.worlds
        n = ids.size
        if n == 0:
            return
        if cfg.friction:
            self.friction[ids] = rng.uniform(*cfg.friction_range, size=n)
            fr = w.per_world("geom_friction")
            fr[np.ix_(ids, self._robot_geoms, [0])] = self.friction[ids, None, None]
        mass_changed = False
        if cfg.base_mass:
            self.mass_offset[ids] = rng.uniform(*cfg.base_mass_range, size=n)
            mass = w.per_world("body_mass")
            mass[ids, self._base] = w.nominal("body_mass")[self._base] + self.mass_offset[ids]
            mass_changed = True
        if cfg.base_com:
            self.com_offset[ids] = rng.uniform(*cfg.base_com_range, size=(n, 3))
            ipos = w.per_world("body_ipos")
            ipos[ids, self._base] = w.nominal("body_ipos")[self._base] + self.com_offset[ids]
            mass_changed = True
        if cfg.motor_strength:
            self.motor_strength[ids] = rng.uniform(*cfg.motor_strength_range, size=(n, self._acts.size))
            gain, bias = w.per_world("actuator_gainprm"), w.per_world("actuator_biasprm")
            g0, b0 = w.nominal("actuator_gainprm"), w.nominal("actuator_biasprm")
            k = self.motor_strength[ids]
            gain[ids[:, None], self._acts[None, :], 0] = g0[self._acts, 0] * k
            bias[ids[:, None], self._acts[None, :], 1] = b0[self._acts, 1] * k
            bias[ids[:, None], self._acts[None, :], 2] = b0[self._acts, 2] * k
        if mass_changed:
            w.set_const(ids)

    def push(self, due: np.ndarray, rng: np.random.Generator) -> None:
        """Set the base xy velocity of worlds where ``due`` (N,) bool to U(-v, v) per axis."""
        if not self.cfg.push or not due.any():
            return
        ids = np.flatnonzero(due)
        v = self.cfg.push_max_vel_xy
        self.worlds.set_base_xy_velocity(ids, rng.uniform(-v, v, size=(ids.size, 2)))

    def delay_steps(self, global_steps: int) -> int:
        """Action delay in control steps in force after ``global_steps`` env steps."""
        if self.cfg.action_delay and global_steps >= self.cfg.delay_after_global_steps:
            return self.cfg.delay_steps
        return 0
