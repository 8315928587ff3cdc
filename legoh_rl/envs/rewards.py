"""The paper's reward table (appendix, "Rewards' definition and weight") as named functions.

Each term is a function ``reward_<name>(s: RewardState) -> (N,)`` of the batched state, unweighted,
written once for numpy arrays and torch tensors (the array API: numpy's own namespace, or
array_api_compat's for torch, on the tensors' device). Each is registered by the :func:`term`
decorator above it, which is the one home of its weights in code: its weight (the paper's table,
or 0.0 for a term that is off unless an experiment sets it) and the robots whose weight differs
(``per_robot``). :data:`REWARD_TERMS` lists them all; per-experiment weights are data, the config's
``env.reward_overrides``, applied last by :func:`reward_weights`. :func:`compute_rewards` returns
every weighted term (for logging) and their sum. As in legged_gym, which the paper's Isaac Gym
code builds on, weights are multiplied by the control period ``dt`` so that the return does not
depend on the control rate. "Tracking Sigma 0.5" in the paper's table is the width of
legged_gym's exp tracking kernel, not a term: the paper's tracking terms are the linear and
exp(-|e|) forms of Extreme Parkour.

Conventions (N worlds, A leg joints):

* velocities: ``lin_vel_w`` base linear velocity in the world frame (N, 3);
  ``ang_vel_b`` base angular velocity in the base frame (N, 3);
  ``gravity_b`` unit gravity in the base frame (N, 3);
* ``goal_dir_w`` unit vector from the base (xy) to the current expert goal (N, 2);
  ``yaw`` base yaw (N,); ``cmd_speed`` commanded speed along the goal direction (N,);
* joints: ``q``, ``dq``, ``dq_prev``, ``q_default`` (N, A) or (A,); ``torques``,
  ``torques_prev`` (N, A); ``q_limits`` (A, 2) soft position limits;
* actions: ``action``, ``action_prev`` (N, A);
* contacts: ``foot_force`` (N, 2, 3) net contact force on each foot (world frame),
  ``penalised_force`` (N, P, 3) on the penalised bodies;
  ``feet_air_time`` (N, 2) seconds in the air before this step's landing, ``first_contact``
  (N, 2) bool, feet touching down this step; ``feet_at_edge`` (N, 2) bool, feet in contact on an
  edge cell; ``terrain_level`` (N,) int;
* ``base_height`` (N,) pelvis height above the terrain under it, ``base_height_target`` float;
  ``base_height_cap`` float or None: the most of a pelvis *above* its target that ``base_height``
  counts, m (None: all of it);
* ``goal_dist`` (N,) distance to the trail end P_B; ``reach_radius`` float;
* ``fell`` (N,) bool, the episode ends by a fall at this step;
* gait shaping (optional, read only by ``feet_clearance`` and ``feet_slip``): ``feet_contact``
  (N, 2) bool, ``foot_lift`` (N, 2) height of each foot above the terrain under it minus its height
  when standing, m, ``foot_vel_xy`` (N, 2, 2) horizontal foot velocities (world frame), m/s;
  ``swing_height`` the target lift of a moving foot, m;
* gait clock (optional, read only by ``gait_contact`` and ``gait_joint_ref``): ``gait_phase``
  (N,) in [0, 1), ``gait_stance`` the stance fraction of the period, ``gait_ref_q`` (N, A) the
  clock's leg-joint reference (:mod:`legoh_rl.envs.gait`).

Beyond the paper's table, two "basic elements" of the legged_gym family (the paper adds basic
terms from Extreme Parkour and Humanoid-Gym without listing them) are available with weight 0
by default: ``alive`` (+1 per step) and ``termination`` (1 on a fall). The oracle recipe turns
them on: without a survival signal a humanoid learning from scratch first finds the "dive
forward" optimum (a few steps of goal-velocity reward, then a fall). Like legged_gym,
``termination`` is added after the ``only_positive_rewards`` clip so that it is never clipped away.

Two clock-free gait-shaping terms of the same family, also weight 0 by default, counter the
shuffle a humanoid falls into when only the table shapes its gait: ``feet_clearance`` (a foot
that moves horizontally should be lifted ``swing_height``, as Walk-These-Ways' clearance term
without its gait clock) and ``feet_slip`` (a foot on the ground should not slide, Humanoid-Gym).
With a gait clock (``HikingEnvConfig.gait_period``), ``gait_contact`` rewards each foot whose
contact state matches the clock (stance for the first ``gait_stance`` of its leg's phase, the
right leg half a period behind the left), and ``gait_joint_ref`` leg joints that follow the
clock's swing reference, as Humanoid-Gym's periodic contact and joint-position rewards
(:mod:`legoh_rl.envs.gait`).

A foothold term, also weight 0 by default, gives the terrain curriculum a signal below the level
where a missed foothold is fatal: ``feet_in_pit`` counts feet in contact whose position lies over
a pit sample (``feet_in_pit`` (N, 2) bool). On level 0 pits are 0.1 m cracks a robot can stand
in, so without it nothing there teaches it to step over them before they are 1 m deep; the
paper's ``feet_edge`` only counts edges above level 3 (``feet_edge_from_level``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.gait import stance_mask
from legoh_rl.envs.robots import ROBOTS
from legoh_rl.registry import Registry

__all__ = [
    "RewardState",
    "RewardTerm",
    "REWARD_TERMS",
    "REWARD_FUNCTIONS",
    "STUDENT_ONLY",
    "AFTER_CLIP",
    "term",
    "reward_weights",
    "compute_rewards",
]

EPS = 1e-5


_xp = namespace_of  # numpy for the host step, array_api_compat's torch for a device-resident one


def _float(x, s: RewardState):
    """``x`` (bool or int) in the state's float dtype (that of ``s.q``: float64 on the host)."""
    return _xp(x).astype(x, s.q.dtype)


@dataclass
class RewardState:
    """Batched quantities the reward terms read; see the module docstring for shapes."""

    lin_vel_w: np.ndarray
    ang_vel_b: np.ndarray
    gravity_b: np.ndarray
    goal_dir_w: np.ndarray
    yaw: np.ndarray
    cmd_speed: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    dq_prev: np.ndarray
    q_default: np.ndarray
    q_limits: np.ndarray
    hip_idx: np.ndarray
    torques: np.ndarray
    torques_prev: np.ndarray
    action: np.ndarray
    action_prev: np.ndarray
    foot_force: np.ndarray
    penalised_force: np.ndarray
    feet_air_time: np.ndarray
    first_contact: np.ndarray
    feet_at_edge: np.ndarray
    terrain_level: np.ndarray
    base_height: np.ndarray
    base_height_target: float
    goal_dist: np.ndarray
    reach_radius: float
    dt: float
    fell: np.ndarray | None = None
    feet_contact: np.ndarray | None = None
    foot_lift: np.ndarray | None = None
    foot_vel_xy: np.ndarray | None = None
    swing_height: float = 0.1
    gait_phase: np.ndarray | None = None
    gait_stance: float = 0.55
    gait_ref_q: np.ndarray | None = None
    base_height_cap: float | None = None
    feet_edge_from_level: int = 4
    feet_in_pit: np.ndarray | None = None

    def require(self, *names: str) -> None:
        """Raise ``ValueError`` naming the optional fields in ``names`` that are unset."""
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            raise ValueError(f"this reward term needs RewardState fields {missing}, which are None")


@dataclass(frozen=True)
class RewardTerm:
    """One reward term and every weight it has in code.

    Attributes:
        name: the term's name (the function's without ``reward_``), the key of weights and logs.
        fn: ``fn(s: RewardState) -> (N,)``, the unweighted term.
        weight: its weight for every robot without a row of its own (the paper's table, or 0.0 for
            a term that is off unless an experiment sets it).
        per_robot: robot name (a key of :data:`legoh_rl.envs.robots.ROBOTS`) -> the weight that
            robot uses instead (the paper's table differs per robot for a few terms).
        student_only: kept only in student mode (dropped for the oracle).
        after_clip: added after the ``only_positive_rewards`` clip, so that it is never clipped away.
    """

    name: str
    fn: Callable[[RewardState], np.ndarray]
    weight: float
    per_robot: Mapping[str, float] = field(default_factory=dict)
    student_only: bool = False
    after_clip: bool = False

    def weight_for(self, robot: str | None) -> float:
        """The weight for ``robot`` (its row if it has one, else :attr:`weight`; ``None``: :attr:`weight`)."""
        return self.weight if robot is None else self.per_robot.get(robot, self.weight)


#: every reward term by name, in the order its weighted values are summed
REWARD_TERMS: Registry[RewardTerm] = Registry("reward term", hint="@term(weight=...) in legoh_rl.envs.rewards adds one")


def _check_weight(value, where: str) -> float:
    """``value`` as a float, or ``ValueError`` naming ``where`` when it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where} must be a finite number (the term's weight), got {value!r}")
    return float(value)


def term(
    weight: float | None = None,
    *,
    per_robot: Mapping[str, float] | None = None,
    student_only: bool = False,
    after_clip: bool = False,
) -> Callable[[Callable], Callable]:
    """Register ``reward_<name>`` in :data:`REWARD_TERMS` with its weight and per-robot weights.

    Use as ``@term(weight=-1.0, per_robot={"g1": -0.5})`` above ``def reward_<name>(s)``; the
    function itself is returned unchanged.

    Raises:
        ValueError: no weight (or a weight that is not a finite number), a per-robot row for a robot
            not in :data:`legoh_rl.envs.robots.ROBOTS`, a function not named ``reward_<name>``, or a
            name registered already; each message names the term.
    """
    if callable(weight):  # bare ``@term``
        raise ValueError(f"reward term {weight.__name__.removeprefix('reward_')!r} has no weight: "
                         "write @term(weight=...) above it")

    def register(fn: Callable) -> Callable:
        if not fn.__name__.startswith("reward_"):
            raise ValueError(f"reward term function {fn.__name__!r} must be named reward_<name>")
        name = fn.__name__[len("reward_"):]
        if weight is None:
            raise ValueError(f"reward term {name!r} has no weight: write @term(weight=...) above it")
        rows = dict(per_robot or {})
        unknown = sorted(set(rows) - set(ROBOTS))
        if unknown:
            raise ValueError(f"reward term {name!r}: per_robot names unknown robots {unknown}; "
                             f"known robots: {sorted(ROBOTS)}")
        REWARD_TERMS.register(name, RewardTerm(
            name=name,
            fn=fn,
            weight=_check_weight(weight, f"reward term {name!r}: weight"),
            per_robot={r: _check_weight(w, f"reward term {name!r}: per_robot[{r!r}]") for r, w in rows.items()},
            student_only=student_only,
            after_clip=after_clip,
        ))
        return fn

    return register


def _sq_sum(x):
    """Sum of squares over the last axis, (..., K) -> (...) (one pass: ``vecdot``)."""
    return _xp(x).vecdot(x, x, axis=-1)


@term(weight=10.0)
def reward_tracking_goal_vel(s: RewardState):
    """min(v_target . v_t, cmd_x) / (cmd_x + eps): speed toward the current expert goal."""
    xp = _xp(s.lin_vel_w)
    along = xp.vecdot(s.goal_dir_w, s.lin_vel_w[:, :2], axis=1)
    return xp.minimum(along, s.cmd_speed) / (s.cmd_speed + EPS)


@term(weight=0.5)
def reward_tracking_yaw(s: RewardState):
    """exp(-|psi_target - psi_t|), the yaw error wrapped to [-pi, pi]."""
    xp = _xp(s.yaw)
    target = xp.atan2(s.goal_dir_w[:, 1], s.goal_dir_w[:, 0])
    err = xp.remainder(target - s.yaw + np.pi, 2.0 * np.pi) - np.pi
    return xp.exp(-xp.abs(err))


@term(weight=-2.0)
def reward_lin_vel_z(s: RewardState):
    """v_z^2."""
    return s.lin_vel_w[:, 2] ** 2


@term(weight=-1.0)
def reward_ang_vel_xy(s: RewardState):
    """w_x^2 + w_y^2 (base frame)."""
    return _sq_sum(s.ang_vel_b[:, :2])


@term(weight=-1.0)
def reward_orientation(s: RewardState):
    """g_x^2 + g_y^2 of gravity in the base frame: zero when upright."""
    return _sq_sum(s.gravity_b[:, :2])


@term(weight=-3.5e-8)
def reward_dof_acc(s: RewardState):
    """sum ((dq_{t-1} - dq_t) / dt)^2."""
    return _sq_sum(s.dq_prev - s.dq) / s.dt**2


@term(weight=-10.0)
def reward_collision(s: RewardState):
    """Number of penalised (non-foot) bodies with a contact force above 0.1 N."""
    return _float(_xp(s.penalised_force).count_nonzero(_sq_sum(s.penalised_force) > 0.1**2, axis=1), s)


@term(weight=-0.01)
def reward_action_rate(s: RewardState):
    """||a_{t-1} - a_t|| (L2 norm, as the paper writes it)."""
    return _xp(s.action).sqrt(_sq_sum(s.action_prev - s.action))


@term(weight=-1.0e-7)
def reward_delta_torques(s: RewardState):
    """sum (tau_t - tau_{t-1})^2."""
    return _sq_sum(s.torques - s.torques_prev)


@term(weight=-1.0e-5)
def reward_torques(s: RewardState):
    """sum tau_t^2."""
    return _sq_sum(s.torques)


@term(weight=-0.5)
def reward_hip_pos(s: RewardState):
    """sum over hip yaw/roll joints of (q - q_default)^2."""
    return _sq_sum((s.q - s.q_default)[:, s.hip_idx])


@term(weight=-0.04)
def reward_dof_error(s: RewardState):
    """sum (q - q_default)^2 over all leg joints."""
    return _sq_sum(s.q - s.q_default)


@term(weight=-1.0)
def reward_feet_stumble(s: RewardState):
    """1 if any foot's horizontal contact force exceeds 4x its vertical one (hitting a riser)."""
    horiz2 = _sq_sum(s.foot_force[..., :2])  # |F_xy| > 4 |F_z|  <=>  |F_xy|^2 > 16 F_z^2
    return _float(_xp(horiz2).any(horiz2 > 16.0 * s.foot_force[..., 2] ** 2, axis=1), s)


@term(weight=-1.0)
def reward_feet_edge(s: RewardState):
    """(terrain_level >= feet_edge_from_level) * number of feet in contact on an edge cell (the
    paper's gate is terrain_level > 3, the default ``feet_edge_from_level`` = 4)."""
    return _float(s.terrain_level >= s.feet_edge_from_level, s) * _xp(s.q).sum(_float(s.feet_at_edge, s), axis=1)


@term(weight=1.0, per_robot={"g1": 0.5})
def reward_feet_air_time(s: RewardState):
    """sum over feet touching down of (T_air - 0.5): rewards steps longer than 0.5 s."""
    return _xp(s.q).sum((s.feet_air_time - 0.5) * _float(s.first_contact, s), axis=1)


@term(weight=-100.0, per_robot={"g1": -35.0})
def reward_base_height(s: RewardState):
    """(h_base - h_target)^2, h_base above the terrain under the base; with ``base_height_cap`` c,
    (min(h_base - h_target, c))^2: a pelvis over a pit or a gap reads the pit floor under it, so
    its height error there is the pit's depth, not a posture error (on flat ground a standing
    pelvis cannot rise c above its target)."""
    err = s.base_height - s.base_height_target
    if s.base_height_cap is not None:
        err = _xp(err).minimum(err, s.base_height_cap)
    return err ** 2


@term(weight=1.0, student_only=True)
def reward_pn_distance(s: RewardState):
    """Point-navigation distance (unified training only): 1 inside the reach radius, else -0.75 d."""
    return _xp(s.goal_dist).where(s.goal_dist < s.reach_radius, 1.0, -0.75 * s.goal_dist)


@term(weight=0.0, per_robot={"g1": -5.0})
def reward_dof_pos_limits(s: RewardState):
    """sum(-min(0, q - q_low) + max(0, q - q_up)): how far joints are past their soft limits."""
    xp = _xp(s.q)
    low = -xp.minimum(s.q - s.q_limits[:, 0], 0.0)
    up = xp.maximum(s.q - s.q_limits[:, 1], 0.0)
    return xp.sum(low + up, axis=1)


@term(weight=0.0)
def reward_alive(s: RewardState):
    """1 per step (not in the paper's table; weight 0 unless set)."""
    return _xp(s.q).ones_like(s.q[:, 0])


@term(weight=0.0, after_clip=True)
def reward_termination(s: RewardState):
    """1 when the episode ends by a fall (not in the paper's table; weight 0 unless set)."""
    return _xp(s.q).zeros_like(s.q[:, 0]) if s.fell is None else _float(s.fell, s)


@term(weight=0.0)
def reward_feet_clearance(s: RewardState):
    """sum over feet of (lift - swing_height)^2 * sqrt(|v_xy|): moving feet should be lifted."""
    s.require("foot_lift", "foot_vel_xy")
    xp = _xp(s.foot_lift)
    speed = xp.sqrt(_sq_sum(s.foot_vel_xy))
    return xp.sum((s.foot_lift - s.swing_height) ** 2 * xp.sqrt(speed), axis=1)


@term(weight=0.0)
def reward_feet_slip(s: RewardState):
    """sum over feet in contact of |v_xy|: feet on the ground should not slide (a shuffle does)."""
    s.require("feet_contact", "foot_vel_xy")
    xp = _xp(s.foot_vel_xy)
    return xp.sum(xp.sqrt(_sq_sum(s.foot_vel_xy)) * _float(s.feet_contact, s), axis=1)


@term(weight=0.0)
def reward_gait_contact(s: RewardState):
    """Number of feet (0-2) whose contact state matches the gait clock's stance/swing pattern."""
    s.require("feet_contact", "gait_phase")
    return _xp(s.q).sum(_float(s.feet_contact == stance_mask(s.gait_phase, s.gait_stance), s), axis=1)


@term(weight=0.0)
def reward_gait_joint_ref(s: RewardState):
    """exp(-2 ||q - q_ref||) - 0.2 min(||q - q_ref||, 0.5): leg joints that follow the clock's
    swing reference ``q_ref = q_default + swing_reference`` (Humanoid-Gym's joint-position term)."""
    s.require("gait_ref_q")
    xp = _xp(s.q)
    d = xp.sqrt(_sq_sum(s.q - s.gait_ref_q))
    return xp.exp(-2.0 * d) - 0.2 * xp.minimum(d, 0.5)


@term(weight=0.0)
def reward_feet_in_pit(s: RewardState):
    """Number of feet in contact over a pit sample (not in the paper's table; weight 0 unless set)."""
    s.require("feet_in_pit")
    return _xp(s.q).sum(_float(s.feet_in_pit, s), axis=1)


REWARD_FUNCTIONS: dict[str, Callable[[RewardState], np.ndarray]] = {n: t.fn for n, t in REWARD_TERMS.items()}
STUDENT_ONLY = frozenset(n for n, t in REWARD_TERMS.items() if t.student_only)
AFTER_CLIP = frozenset(n for n, t in REWARD_TERMS.items() if t.after_clip)


def reward_weights(
    robot: str | None = None,
    overrides: Mapping[str, float] | None = None,
    student: bool = False,
) -> dict[str, float]:
    """The weights in force: each term's weight, the robot's own where it has one, then ``overrides``.

    Args:
        robot: a key of :data:`legoh_rl.envs.robots.ROBOTS` (case-insensitive), or ``None`` for the
            terms' weights without any robot's rows.
        overrides: term -> weight (an experiment's ``env.reward_overrides``), applied last.
        student: keep the :data:`STUDENT_ONLY` terms.

    Returns:
        term -> weight in :data:`REWARD_TERMS`' order, terms with weight 0 dropped.

    Raises:
        ValueError: an unknown robot or an override naming an unknown term (each message lists the
            known ones).
    """
    if robot is not None:
        robot = str(robot).lower()
        if robot not in ROBOTS:
            raise ValueError(f"unknown robot {robot!r} for the reward weights; known robots: {sorted(ROBOTS)}")
    weights = {name: t.weight_for(robot) for name, t in REWARD_TERMS.items()}
    for name, value in (overrides or {}).items():
        REWARD_TERMS.lookup(name)
        weights[name] = float(value)
    if not student:
        for name in STUDENT_ONLY:
            weights.pop(name, None)
    return {k: v for k, v in weights.items() if v != 0.0}


def compute_rewards(
    s: RewardState, weights: dict[str, float], only_positive: bool = False
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Weighted terms and their sum.

    Args:
        s: the batched state.
        weights: term name -> weight (see :func:`reward_weights`).
        only_positive: clip the sum at 0, then add the :data:`AFTER_CLIP` terms.

    Returns:
        total: (N,) sum of ``weight * term * dt``;
        terms: name -> (N,) ``weight * term * dt``; arrays of ``s``'s kind (numpy or torch).
    """
    terms = {name: w * s.dt * REWARD_FUNCTIONS[name](s) for name, w in weights.items()}
    before = [v for k, v in terms.items() if k not in AFTER_CLIP]
    after = [v for k, v in terms.items() if k in AFTER_CLIP]
    xp = _xp(s.q)
    total = xp.sum(xp.stack(before), axis=0) if before else xp.zeros_like(s.q[:, 0])  # one pass over (K, N)
    if only_positive:
        total = xp.maximum(total, 0.0)
    if after:
        total = total + xp.sum(xp.stack(after), axis=0)
    return total, terms
