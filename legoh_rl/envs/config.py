"""Configuration of the hiking env: one dataclass, each field with its default and its kind.

The recipes' ``env`` section is this dataclass (hydra group ``env/hiking``, built by
:mod:`legoh_rl.training.config_store`): every field, nested sections included, is a setting
(``env.decimation=2``, ``env.domain_rand.push=false``, ``env.depth_camera.noise_std=0.01``), but
``mode`` and ``device``, which the recipe sets. Each field's allowed values are its kind
(:func:`legoh_rl.kinds.setting`), checked by ``__post_init__`` with how the fields combine.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from legoh_rl.envs.curriculum import CurriculumConfig
from legoh_rl.envs.randomization import DOMAIN_RAND_TERMS, DomainRandConfig
from legoh_rl.envs.robots import ROBOTS
from legoh_rl.envs.sensors import DepthCameraConfig
from legoh_rl.envs.trails import ALL_CATEGORIES, CATEGORIES, NUM_LEVELS
from legoh_rl.kinds import (
    Choice,
    Flag,
    Integer,
    ListOf,
    MapOf,
    Name,
    Number,
    OneOf,
    check_fields,
    setting,
)

__all__ = ["HikingEnvConfig", "MODES", "PHYSICS", "ANG_VEL_SCALE", "DOF_VEL_SCALE", "LIN_VEL_SCALE"]

MODES = ("oracle", "student", "eval")
PHYSICS = ("mujoco", "warp")  # env.physics: C MuJoCo threads or MuJoCo Warp
# Observation scales (legged_gym's): keep every input of order one.
ANG_VEL_SCALE = 0.25
DOF_VEL_SCALE = 0.05
LIN_VEL_SCALE = 2.0


def _reward_terms() -> tuple[str, ...]:
    """The reward terms ``reward_overrides`` may weight (read when checked)."""
    from legoh_rl.envs.rewards import REWARD_FUNCTIONS

    return tuple(REWARD_FUNCTIONS)


@dataclass
class HikingEnvConfig:
    """Everything that defines a :class:`~legoh_rl.envs.hiking.HikingEnv`.

    Attributes:
        robot: ``"h1"`` or ``"g1"``.
        freeze_ankle_roll: G1 only, 10 actions instead of 12.
        num_envs: N, worlds stepped together (``batch_size = [N]``).
        mode: ``"oracle"`` (privileged training: no depth), ``"student"`` (unified training:
            depth and the privileged part, which the frozen teacher reads) or ``"eval"``
            (benchmark: 0.89 m goal radius, 30 s episodes, no curriculum, no randomisation
            unless ``eval_domain_rand``).
        categories: trail categories of the grid.
        category_weights: share of the worlds each category gets, one positive weight per entry of
            ``categories`` (None: equal shares). Worlds keep their category, so this sets how much
            of each batch the hard categories fill (counts by largest remainder).
        levels: difficulty levels the worlds start on (the grid always holds all levels).
        variants: seeded variants per category and level.
        pit_depths: per level, how deep gap and stepping-stone pits go at most, m (None: the
            benchmark's 0.1 m on level 0, 1.0 m above). A training schedule can put rungs between
            level 0's cracks and level 1's drops; the eval mode refuses it (the benchmark's
            terrain is fixed).
        foot_scan: append the foot scan to ``scandots``: terrain heights relative to each foot's
            sole at :data:`~legoh_rl.envs.sensors.FOOT_SCAN_OFFSETS` (45 points per foot, 0.05 m
            apart, in the foot's yaw frame), so ``scandots`` grows from (132,) to (132 + 2 x 45,).
            A privileged input of the oracle (the student reads no scandots; its env computes
            them for its teacher). Not in the paper (docs/observations.md).
        foot_scan_far: extend the foot scan forward: heights at
            :data:`~legoh_rl.envs.sensors.FOOT_SCAN_FAR_OFFSETS` (35 points per foot, 0.35-0.65 m
            ahead of the ankle) after the near scan's, so ``scandots`` grows to (132 + 2 x 45 + 2 x 35,).
            Needs ``foot_scan``. Not in the paper (docs/observations.md).
        depth: render the head depth camera (default: off in oracle mode, on otherwise).
        depth_camera: resolution (64x64 default; 128x128 paper), clipping, noise.
        perception_every: control steps per depth frame (5 = 10 Hz at 50 Hz control).
        perception_clock: whose steps ``perception_every`` counts: ``"episode"`` (each world's
            own episode, so worlds tick out of step once they reset at different times) or
            ``"global"`` (the env's step count: every world ticks at once, as one camera clock
            would, so the student's perception runs once per tick on the whole batch instead of
            on a fifth of it every step; a reset world renders its first frame besides). Not in
            the paper; BENCHMARKS.md, "The perception clock".
        num_goals: N anticipated/expert goals exposed (3).
        cmd_speed: commanded walking speed for the tracking reward and curriculum, m/s.
        episode_length_s: training episode timeout (eval: ``eval_episode_length_s``).
        goal_radius: trail end reached (training) / ``eval_goal_radius`` in eval mode, m.
        goal_reach_radius: an expert goal counts as passed within this distance, m.
        fall_roll_pitch: |roll| or |pitch| above this ends the episode as a fall, rad.
        fall_height_ratio: base height above the terrain below this x target height: fall.
        timestep, decimation: physics step (s) and substeps per control step.
        num_threads: physics threads (None = all usable CPUs).
        physics: the physics backend: ``mujoco`` (C MuJoCo in threads, ``mujoco.batch``) or
            ``warp`` (MuJoCo Warp on ``device``; needs ``pip install 'legoh-rl[gpu]'``;
            docs/gpu_physics.md).
        resident: with ``physics="warp"``, keep the step on ``device``: the state is read from
            the simulation's own arrays, and observations, rewards, terminations and episode
            metrics are torch tensors there, with no copy through the host in a step (resets,
            the curriculum and a host-marched depth image still cross). ``None``: on when
            ``physics="warp"`` and ``device`` is a CUDA device; ``True`` also runs it on Warp's
            CPU device (the tests' parity checks).
        action_clip: actions are clipped to [-clip, clip] (the action spec's bounds).
        spawn_jitter_xy, spawn_jitter_yaw: random spawn offsets in training (m, rad).
        swing_height: target lift of a moving foot for the ``feet_clearance`` term, m.
        gait_period: period of a gait clock, s (0: no clock). When positive, ``proprio`` ends
            with (sin 2 pi phi, cos 2 pi phi) of the clock phase phi = t / period mod 1 (t the
            episode time), and the ``gait_contact`` reward term can be used.
        gait_stance: fraction of the period each foot is meant to be on the ground (the left leg
            from phase 0, the right from phase 0.5).
        gait_amplitude: how far the clock's swing reference folds the swinging leg, rad (hip
            pitch and ankle pitch by this, knee by twice this; ``gait_joint_ref`` term).
        gait_feedforward: gain of the swing reference added to the PD targets (0: off). With 1,
            ``q* = q_default + swing_reference(phi) + action_scale * a``: the clock steps the legs
            by itself and the policy's action is a residual on that gait. Not in the paper: a
            structural prior for small sample budgets (docs/history/results-sessions-1-12.md, run 13).
        feet_edge_from_level: lowest terrain level on which the ``feet_edge`` term counts (paper:
            4, "terrain_level > 3"). Lower values penalise footholds on edges and in pits already on
            easy trails, where a missed foothold costs a stumble, not a fall.
        base_height_error_cap: the most of a pelvis above its target height that the
            ``base_height`` term counts, m (None: all of it, the paper's term). The term measures
            the pelvis against the terrain right under it, so over a 1 m pit it reads a 1 m error
            (-2 per step at H1's weight, more than every positive term: with
            ``only_positive_rewards`` a step over a pit earns nothing). Not in the paper.
        reward_overrides: term -> weight, on top of the paper's table and the robot's rows.
        category_reward_scales: trail category -> {term: scale}: on worlds whose current trail is
            of that category, the term's weight is multiplied by the scale (>= 0; categories and
            terms not named keep 1). E.g. ``{gap: {gait_contact: 0}}`` frees the feet from the
            gait clock's contact pattern on the Gap trails only. Each term named must be weighted
            (the env refuses one that is not). Not in the paper.
        only_positive_rewards: clip each step's total reward at 0 (legged_gym and Extreme
            Parkour do; otherwise early, penalty-dominated returns teach the policy to fall fast
            to end its episode). The logged terms are left unclipped; ``termination`` is added
            after the clip.
        domain_rand, curriculum: see their modules.
        eval_domain_rand: in ``"eval"`` mode, draw ``domain_rand``'s randomisation too (friction,
            base mass and CoM, motor strength, pushes, and the action delay from the first step):
            the benchmark under the training's perturbations, a robustness test. True: every
            term; a tuple of :data:`~legoh_rl.envs.randomization.DOMAIN_RAND_TERMS`: those terms
            alone (which perturbation costs a policy most). Off by default: the benchmark runs
            the nominal robot.
        trail_tile_size: (length, width) of a trail tile, m (passed to the trail grid).
        seed: seeds the trails, spawns, randomisation and noise.
        device: torch device of the output tensors.
    """

    robot: str = setting("h1", Choice(lambda: tuple(ROBOTS), what="robot"))
    freeze_ankle_roll: bool = setting(False, Flag())
    num_envs: int = setting(64, Integer(1))
    mode: str = setting("oracle", Choice(MODES, what="mode"))
    categories: tuple[str, ...] = setting(CATEGORIES,
                                          ListOf(Choice(ALL_CATEGORIES, what="trail category"), single=True))
    category_weights: tuple[float, ...] | None = setting(None, ListOf(Number(0, low_open=True), nullable=True))
    levels: tuple[int, ...] = setting((0,), ListOf(Integer(0, NUM_LEVELS - 1)))
    variants: int = setting(2, Integer(1))
    pit_depths: tuple[float, ...] | None = setting(None, ListOf(Number(0, low_open=True), nullable=True))
    foot_scan: bool = setting(False, Flag())
    foot_scan_far: bool = setting(False, Flag())
    depth: bool | None = setting(None, Flag(nullable=True))
    depth_camera: DepthCameraConfig = field(default_factory=DepthCameraConfig)
    perception_every: int = setting(5, Integer(1))
    perception_clock: str = setting("episode", Choice(("episode", "global"), what="perception clock"))
    num_goals: int = setting(3, Integer(1))
    cmd_speed: float = setting(0.8, Number(0, low_open=True))
    episode_length_s: float = setting(20.0, Number(0, low_open=True))
    eval_episode_length_s: float = setting(30.0, Number(0, low_open=True))
    goal_radius: float = setting(0.5, Number(0, low_open=True))
    eval_goal_radius: float = setting(0.89, Number(0, low_open=True))
    goal_reach_radius: float = setting(0.5, Number(0, low_open=True))
    fall_roll_pitch: float = setting(1.0, Number(0, low_open=True))
    fall_height_ratio: float = setting(0.5, Number(0))
    timestep: float = setting(0.005, Number(0, low_open=True))
    decimation: int = setting(4, Integer(1))
    num_threads: int | None = setting(None, Integer(1, nullable=True))
    physics: str = setting("mujoco", Choice(PHYSICS))
    resident: bool | None = setting(None, Flag(nullable=True))
    action_clip: float = setting(5.0, Number(0, low_open=True))
    spawn_jitter_xy: float = setting(0.2, Number(0))
    spawn_jitter_yaw: float = setting(0.3, Number(0))
    swing_height: float = setting(0.1, Number(0, low_open=True))
    gait_period: float = setting(0.0, Number(0))
    gait_stance: float = setting(0.55, Number(0, 1, low_open=True, high_open=True))
    gait_amplitude: float = setting(0.25, Number(0))
    gait_feedforward: float = setting(0.0, Number(0))
    feet_edge_from_level: int = setting(4, Integer(0))
    base_height_error_cap: float | None = setting(None, Number(0, nullable=True))
    reward_overrides: dict[str, float] = setting(None, MapOf(Choice(_reward_terms, what="reward term"), Number()),
                                                 factory=dict)
    category_reward_scales: dict[str, dict[str, float]] = setting(
        None, MapOf(Choice(ALL_CATEGORIES, what="trail category"),
                    MapOf(Choice(_reward_terms, what="reward term"), Number(0))), factory=dict)
    only_positive_rewards: bool = setting(True, Flag())
    domain_rand: DomainRandConfig = field(default_factory=DomainRandConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    eval_domain_rand: bool | tuple[str, ...] = setting(False, OneOf(
        (Flag(), Choice(DOMAIN_RAND_TERMS), ListOf(Choice(DOMAIN_RAND_TERMS, what="domain randomisation term"))),
        text=f"true, false or a non-empty list of terms from {list(DOMAIN_RAND_TERMS)}"))
    seed: int = setting(0, Integer(0))
    device: str = setting("cpu", Name())

    def __post_init__(self) -> None:
        check_fields(self)  # each field against its kind (legoh_rl/kinds.py); below: how they combine
        for term in ("gait_contact", "gait_joint_ref"):
            if self.reward_overrides.get(term, 0.0) and not self.gait_period:
                raise ValueError(f"reward term {term} needs a gait clock: set gait_period > 0 "
                                 f"(got gait_period={self.gait_period!r})")
        if self.foot_scan_far and not self.foot_scan:
            raise ValueError("foot_scan_far=True extends the foot scan: it needs foot_scan=True (got foot_scan=False)")
        if self.gait_feedforward and not self.gait_period:
            raise ValueError(f"gait_feedforward={self.gait_feedforward!r} needs a gait clock: set gait_period > 0 "
                             f"(got gait_period={self.gait_period!r})")
        if not isinstance(self.eval_domain_rand, bool):
            terms = self.eval_domain_rand
            self.eval_domain_rand = (terms,) if isinstance(terms, str) else tuple(terms)
        if self.eval_domain_rand and not self.is_eval:
            raise ValueError(f"eval_domain_rand randomises the evaluation: it needs mode='eval', got mode={self.mode!r} "
                             "(training modes draw domain_rand already)")
        if self.resident and self.physics != "warp":
            raise ValueError(f"resident=True keeps the step on the simulation's device: it needs physics='warp', "
                             f"got physics={self.physics!r}")
        if self.depth_camera.source == "warp" and self.physics != "warp":
            raise ValueError(f"depth_camera.source='warp' casts the simulation's own rays: it needs physics='warp', "
                             f"got physics={self.physics!r}")
        if isinstance(self.categories, str):  # one category: a bare name
            self.categories = (self.categories,)
        if self.category_weights is not None:
            weights = tuple(self.category_weights)
            if len(weights) != len(self.categories):
                raise ValueError(f"category_weights must hold one positive weight per category "
                                 f"{list(self.categories)}, got {list(weights)}")
        if self.pit_depths is not None:
            if self.mode == "eval":
                raise ValueError(f"pit_depths={list(self.pit_depths)} is a training setting: the eval mode keeps the "
                                 "benchmark's pits (0.1 m on level 0, 1.0 m above)")
            self.pit_depths = tuple(float(d) for d in self.pit_depths)

    @property
    def depth_enabled(self) -> bool:
        """Whether the depth camera is rendered."""
        return self.mode != "oracle" if self.depth is None else bool(self.depth)

    @property
    def step_on_device(self) -> bool:
        """Whether the step runs device-resident (``resident``, its ``None`` resolved)."""
        if self.resident is None:
            return self.physics == "warp" and str(self.device).startswith("cuda")
        return bool(self.resident)

    @property
    def active_domain_rand(self) -> DomainRandConfig:
        """The randomisation in force: ``domain_rand`` in training; in eval mode none, or with
        ``eval_domain_rand`` ``domain_rand`` (or the terms it names) with its action delay on from
        the first step."""
        if not self.is_eval:
            return self.domain_rand
        if self.eval_domain_rand is True:
            return replace(self.domain_rand, delay_after_global_steps=0)
        if self.eval_domain_rand:
            return replace(self.domain_rand.only(self.eval_domain_rand), delay_after_global_steps=0)
        return DomainRandConfig.off()

    @property
    def is_eval(self) -> bool:
        """Evaluation protocol in force."""
        return self.mode == "eval"

    @property
    def reach_radius(self) -> float:
        """Distance to P_B that ends an episode as a success."""
        return self.eval_goal_radius if self.is_eval else self.goal_radius

    @property
    def max_episode_s(self) -> float:
        """Episode timeout, s."""
        return self.eval_episode_length_s if self.is_eval else self.episode_length_s
