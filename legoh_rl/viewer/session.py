"""The simulation side of the viewers: an env, a policy, a step, and a snapshot to draw.

:class:`PlaySession` runs a checkpoint (``.pt``, an ``.onnx`` export, or ``zero``) on a chosen
trail with the evaluation's own loaders (:func:`~legoh_rl.training.policies.load_policy`), so
what a viewer shows is what ``recipes/evaluate.py`` measures: the eval-mode env (no
randomisation, no curriculum), the deterministic policy, episodes that end on success, a fall or
the 30 s limit and restart at P_A.

The trail is the benchmark's tile (category, level, variant) of the trail seed: the same
``build_trail`` call that builds that tile of the evaluation grid. With ``num_robots`` > 1 the
robots walk variants ``variant``, ``variant + 1``, ... side by side (one lane each), so they do not
repeat one another's deterministic episode.

No viewer is imported here: :meth:`PlaySession.step` returns a :class:`Snapshot` of plain numpy
arrays (robot geom poses, trail points, goals, the student's anticipated goals and depth image,
metrics), which the browser viewer (:mod:`legoh_rl.viewer.web`), MuJoCo's native viewer
(:mod:`legoh_rl.viewer.native`) and the tests read.
"""

from __future__ import annotations

import operator
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from legoh_rl.envs.robots import ROBOT_GEOM_GROUPS, ROBOTS
from legoh_rl.envs.trail_source import GridTrails
from legoh_rl.envs.trails import (
    NUM_LEVELS,
    TrailGrid,
    TrailGridConfig,
    build_trail,
    check_category,
    check_level,
)
from legoh_rl.viewer.geometry import GeomMesh, geom_world_poses, robot_geoms, static_geoms

__all__ = ["MAX_ROBOTS", "PlaySession", "Snapshot", "TrailChoice", "LaneTrails", "anticipated_goals", "checkpoint_robot"]

#: the most robots a session runs side by side (one lane, i.e. one trail variant, each)
MAX_ROBOTS = 16
#: trail grid layout of the evaluation grid (``TrailGridConfig`` defaults): the lanes are its tiles
_BORDER = TrailGridConfig().border


@dataclass(frozen=True)
class TrailChoice:
    """What a session runs on: the robot and the trail (category, level, variant).

    Every field is checked when the choice is made; a bad value raises ``ValueError`` naming it
    and listing the valid ones.
    """

    robot: str
    category: str
    level: int
    variant: int = 0

    def __post_init__(self) -> None:
        robot = self.robot.lower() if isinstance(self.robot, str) else self.robot
        if robot not in ROBOTS:
            raise ValueError(f"unknown robot {self.robot!r}; valid robots: {', '.join(ROBOTS)}")
        object.__setattr__(self, "robot", robot)
        check_category(self.category)
        object.__setattr__(self, "level", check_level(self.level))
        try:
            variant = operator.index(self.variant)
        except TypeError:
            variant = None
        if variant is None or isinstance(self.variant, bool) or variant < 0:
            raise ValueError(f"trail variant must be a non-negative integer, got {self.variant!r}")
        object.__setattr__(self, "variant", variant)


class LaneTrails(GridTrails):
    """Trails for a session: variants ``variant .. variant + lanes - 1`` of one (category, level)
    side by side, as the env's :class:`~legoh_rl.envs.hiking.TrailSource`.

    Each lane (tile) is given its own category index, so that ``HikingEnv.assign_tiles`` can pin
    world ``i`` to lane ``i`` (the env draws a world's tile among those of its cell);
    ``categories`` repeats the category's name for every lane. ``num_levels`` is the benchmark's
    (a level-3 tile is still level 3).
    """

    def __init__(self, category: str, level: int, variant: int = 0, lanes: int = 1, seed: int = 0) -> None:
        trails = [build_trail(category, level, seed, variant + k) for k in range(lanes)]
        t = trails[0]
        cfg = TrailGridConfig(categories=(category,), num_levels=1, variants=lanes, tile_length=t.length,
                              tile_width=t.width, resolution=t.resolution, border=_BORDER, seed=seed,
                              max_goals=max(TrailGridConfig().max_goals, *(len(tr.goals) for tr in trails)))
        super().__init__(TrailGrid([trails], cfg))
        self.num_levels = NUM_LEVELS
        self.tile_category = np.arange(lanes, dtype=np.int64)
        self.categories = (category,) * lanes


@dataclass
class Snapshot:
    """The state of a session's N robots after a step (numpy arrays, world frame, metres).

    Attributes:
        step: control steps since the session's env was built.
        episode_time: (N,) s into each robot's current episode.
        base_pos: (N, 3) positions of the floating base (the pelvis); ``base_yaw`` (N,) headings, rad.
        geom_pos: (N, G, 3) and ``geom_quat`` (N, G, 4) (w, x, y, z) world poses of the robot's
            geoms :attr:`PlaySession.robot_meshes` (same order).
        start, end, waypoint: (N, 3) P_A, P_B and the intermediate waypoint of each robot's trail.
        expert_goals: (N, M, 3) the trail's expert goals, the last of them P_B (padded by
            repeating P_B); ``num_expert_goals`` (N,) how many are real; ``goal_index`` (N,) the
            current one.
        anticipated_goals: (N, K, 3) a student's anticipated goals g_1..g_K (its ``goals_uni``
            directions, turned to the world frame, each at the distance of the expert goal it
            anticipates); ``None`` for a policy without them (oracle, zero).
        anticipated_dirs: (N, K, 2) those directions, unit world-frame xy vectors; or ``None``.
        depth: (N, H, W) float32 in [0, 1], the student's last depth image; ``None`` without a camera.
        distance_to_go: (N,) horizontal straight-line distance from the base to P_B, m (what the
            env's episode end and trail-completion metric measure).
        done: (N,) bool: the robot's episode ended at this step (it is back at P_A now).
        outcome: per robot, how its last episode ended (``"success"``, ``"fall"``, ``"timeout"``)
            or ``""`` before its first end.
        episodes, successes, falls, timeouts: episodes ended since the trail was chosen, all robots.
    """

    step: int
    episode_time: np.ndarray
    base_pos: np.ndarray
    base_yaw: np.ndarray
    geom_pos: np.ndarray
    geom_quat: np.ndarray
    start: np.ndarray
    end: np.ndarray
    waypoint: np.ndarray
    expert_goals: np.ndarray
    num_expert_goals: np.ndarray
    goal_index: np.ndarray
    anticipated_goals: np.ndarray | None
    anticipated_dirs: np.ndarray | None
    depth: np.ndarray | None
    distance_to_go: np.ndarray
    done: np.ndarray
    outcome: list[str]
    episodes: int
    successes: int
    falls: int
    timeouts: int


def checkpoint_robot(checkpoint: str | Path) -> str | None:
    """The robot a checkpoint drives (read from its meta block), or ``None`` for ``"zero"``.

    Raises:
        FileNotFoundError: no checkpoint (or ONNX export) at the path.
        ValueError: a ``.pt`` file without a ``meta.robot`` entry (names the file).
    """
    if str(checkpoint) == "zero":
        return None
    if str(checkpoint).endswith(".onnx"):
        from legoh_rl.training.onnx_policy import read_metadata, resolve_onnx

        files = resolve_onnx(checkpoint)
        return str(read_metadata(next(iter(files.values())))["meta"]["robot"])
    from legoh_rl.training.checkpoint import load_checkpoint

    robot = load_checkpoint(checkpoint).get("meta", {}).get("robot")
    if robot is None:
        raise ValueError(f"{checkpoint}: the checkpoint names no robot (meta.robot); is it from oracle_ppo.py "
                         "or unified.py?")
    return str(robot)


class PlaySession:
    """A policy running live on a chosen trail: build, step, snapshot, change the trail.

    Args:
        checkpoint: a ``.pt`` checkpoint, a ``.onnx`` export (``recipes/export_policy.py``) or
            ``"zero"`` (the PD hold at the default pose).
        robot: the robot; ``None``: the checkpoint's (``h1`` for ``zero``). Another robot than the
            checkpoint's needs a policy for it: ``checkpoints[robot]``, or a file named like the
            checkpoint with the robot's name in place of the checkpoint's (``student_h1.pt`` ->
            ``student_g1.pt``).
        category, level, variant: the trail (:class:`TrailChoice`).
        num_robots: robots, one lane (trail variant) each, 1..:data:`MAX_ROBOTS`.
        seed: the trail seed (the evaluation's ``seed``) and the env's.
        device: where the policy runs (``cpu``, ``cuda``, ...).
        checkpoints: ``{robot: checkpoint}`` for the robots the checkpoint does not drive.

    Raises:
        ValueError: a bad robot, category, level, variant or robot count (the message names the
            value), or no policy for the robot.
        FileNotFoundError: no checkpoint at the path.
    """

    def __init__(self, checkpoint: str | Path, robot: str | None = None, category: str = "gap", level: int = 2,
                 variant: int = 0, num_robots: int = 1, seed: int = 0, device: str | torch.device = "cpu",
                 checkpoints: dict[str, str] | None = None) -> None:
        self.num_robots = _count("num_robots", num_robots, 1, MAX_ROBOTS)
        self.seed = _count("seed", seed, 0, None)
        self.device = torch.device(device)
        self.checkpoint = str(checkpoint)
        self.checkpoints = {}
        for name, path in (checkpoints or {}).items():
            key = TrailChoice(name, "gap", 0).robot  # checks the robot's name
            self.checkpoints[key] = str(path)
        self._robot_of = {}  # checkpoint path -> its robot (read once)
        own = self._robot_of_checkpoint(self.checkpoint)
        self.choice = TrailChoice(robot if robot is not None else (own or "h1"), category, level, variant)
        self.env = None
        self._build(self.choice)

    # ------------------------------------------------------------------ building
    def _robot_of_checkpoint(self, path: str) -> str | None:
        if path not in self._robot_of:
            self._robot_of[path] = checkpoint_robot(path)
        return self._robot_of[path]

    def policy_for(self, robot: str) -> str:
        """The checkpoint that drives ``robot`` (see the class docstring).

        Raises:
            ValueError: none is known; the message names the robot, the checkpoint's robot and
                how to give one (``checkpoints.<robot>=PATH``).
        """
        robot = TrailChoice(robot, "gap", 0).robot
        if robot in self.checkpoints:
            return self.checkpoints[robot]
        own = self._robot_of_checkpoint(self.checkpoint)
        if own is None or own == robot:
            return self.checkpoint
        path = Path(self.checkpoint)
        sibling = path.with_name(re.sub(rf"(?<![a-z0-9]){re.escape(own)}(?![a-z0-9])", robot, path.name))
        if sibling != path and (sibling.is_file() or (sibling.suffix == ".onnx" and _onnx_exists(sibling))):
            return str(sibling)
        beside = f" and no {sibling.name} lies beside it" if sibling != path else ""
        raise ValueError(f"no policy for robot {robot!r}: {self.checkpoint} drives {own!r}{beside}; give one with "
                         f"checkpoints.{robot}=PATH")

    def _build(self, choice: TrailChoice) -> None:
        """Build the env and policy of ``choice``; the session keeps its old ones if this fails."""
        from legoh_rl.training.evaluation import EvalProtocol
        from legoh_rl.training.policies import load_policy

        path = self.policy_for(choice.robot)
        trails = LaneTrails(choice.category, choice.level, choice.variant, self.num_robots, self.seed)
        protocol = EvalProtocol(categories=(choice.category,), levels=(choice.level,),
                                robots_per_cell=self.num_robots, seed=self.seed)
        env, policy, kind = load_policy(path, protocol, robot=choice.robot, variants=1, seed=self.seed,
                                        num_threads=1, trails=trails, device=self.device)
        base = getattr(env, "base_env", env)
        if base.cfg.robot != choice.robot:
            env.close()
            raise ValueError(f"{path} drives robot {base.cfg.robot!r}, not {choice.robot!r}")
        if self.env is not None:
            self.env.close()
        self.env, self.policy, self.kind, self.base, self.policy_path = env, policy, kind, base, path
        self.choice = choice
        model = base.worlds.model
        #: the robot's geoms as meshes in their own frames (the visual meshes when it has them)
        self.robot_meshes: list[GeomMesh] = robot_geoms(model, ROBOT_GEOM_GROUPS[0])
        self._robot_geom_ids = np.array([m.geom for m in self.robot_meshes], dtype=np.int64)
        #: the trail's heightfield and obstacles: ``[(mesh, world pos, world quat), ...]``
        self.terrain_meshes = static_geoms(model)
        base.assign_tiles(np.full(self.num_robots, choice.level), np.arange(self.num_robots))
        self.steps = 0
        self._clear_tallies()
        self.reset()

    def change(self, robot: str | None = None, category: str | None = None, level: int | None = None,
               variant: int | None = None) -> bool:
        """Run on another robot or trail (fields left ``None`` stay): rebuilds the env and policy.

        Returns:
            whether anything changed (False: the same choice, nothing rebuilt).

        Raises:
            ValueError: a bad value (the message names it), or no policy for the robot; the
                session then runs on as before.
        """
        old = self.choice
        new = TrailChoice(old.robot if robot is None else robot, old.category if category is None else category,
                          old.level if level is None else level, old.variant if variant is None else variant)
        if new == old:
            return False
        self._build(new)
        return True

    def reset(self) -> Snapshot:
        """Put every robot back at P_A (new episodes; the tallies stay)."""
        self.env.set_seed(self.seed)
        self.td = self.env.reset()
        self._goals_uni = None
        self._done = np.zeros(self.num_robots, dtype=bool)
        return self.snapshot()

    def _clear_tallies(self) -> None:
        self.episodes = self.successes = self.falls = self.timeouts = 0
        self.outcome = [""] * self.num_robots

    # ------------------------------------------------------------------ stepping
    @property
    def dt(self) -> float:
        """Seconds of simulated time per control step (the policy's period)."""
        return float(self.base.dt)

    @property
    def is_student(self) -> bool:
        """Whether the policy predicts anticipated goals (``goals_uni``): a student."""
        return self.kind.startswith("student")

    def step(self) -> Snapshot:
        """One control step of every robot (deterministic actions); robots whose episode ended
        start a new one at P_A. Returns the :class:`Snapshot` after it."""
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            td = self.policy(self.td)
            goals = td.get("goals_uni", None)
            self._goals_uni = None if goals is None else goals.detach().to("cpu", torch.float64).numpy().copy()
            out, self.td = self.env.step_and_maybe_reset(td)
        nxt = out["next"]
        done = nxt["done"].reshape(-1).cpu().numpy()
        if done.any():
            success = nxt["episode", "success"].reshape(-1).cpu().numpy() > 50.0  # 100 on success
            terminated = nxt["terminated"].reshape(-1).cpu().numpy()
            for w in np.flatnonzero(done):
                kind = "success" if success[w] else "fall" if terminated[w] else "timeout"
                self.outcome[w] = kind
            self.episodes += int(done.sum())
            self.successes += int((done & success).sum())
            self.falls += int((done & terminated & ~success).sum())
            self.timeouts += int((done & ~terminated).sum())
        self._done = done
        self.steps += 1
        return self.snapshot()

    def snapshot(self) -> Snapshot:
        """The robots' current state (see :class:`Snapshot`); fresh arrays."""
        b = self.base
        b.worlds.refresh_host()
        xpos, xquat = b.worlds.xpos, b.worlds.xquat
        pos = np.array(b.worlds.qpos[:, 0:3])  # the floating base, as the env's observations read it
        q = b.worlds.qpos[:, 3:7]
        yaw = np.arctan2(2.0 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1.0 - 2.0 * (q[:, 2] ** 2 + q[:, 3] ** 2))
        gpos, gquat = geom_world_poses(b.worlds.model, self._robot_geom_ids, xpos, xquat)
        ng = np.asarray(b.num_goals) - 1  # the goals before P_B
        anticipated = dirs = None
        if self._goals_uni is not None:
            dirs, anticipated = anticipated_goals(self._goals_uni, pos, yaw, b.goals, b.goal_idx, b.num_goals,
                                                  b.trails.height_at)
        depth = None
        if b.depth is not None:
            d = b.depth if isinstance(b.depth, np.ndarray) else b.depth.detach().cpu().numpy()
            depth = np.array(d[:, 0], dtype=np.float32)
        return Snapshot(
            step=self.steps, episode_time=np.asarray(b.episode_step, dtype=np.float64) * b.dt, base_pos=pos,
            base_yaw=yaw, geom_pos=gpos, geom_quat=gquat, start=np.array(b.start), end=np.array(b.end),
            waypoint=np.array(b.waypoint), expert_goals=np.array(b.goals[:, :-1]), num_expert_goals=ng.copy(),
            goal_index=np.array(b.goal_idx), anticipated_goals=anticipated, anticipated_dirs=dirs, depth=depth,
            distance_to_go=np.linalg.norm(b.end[:, :2] - pos[:, :2], axis=1), done=self._done.copy(),
            outcome=list(self.outcome), episodes=self.episodes, successes=self.successes, falls=self.falls,
            timeouts=self.timeouts)

    def close(self) -> None:
        """Free the env (idempotent)."""
        env, self.env = self.env, None
        if env is not None:
            env.close()


def anticipated_goals(goals_uni: np.ndarray, pos: np.ndarray, yaw: np.ndarray, goals: np.ndarray,
                      goal_index: np.ndarray, num_goals: np.ndarray, height_at) -> tuple[np.ndarray, np.ndarray]:
    """A student's anticipated goals in the world frame, to draw.

    ``goals_uni`` (N, K, 2) are (cos, sin) directions in each robot's yaw frame, as the
    ``expert_goals`` observation gives the expert's (the k-th row: the k-th goal from the current
    one). Each is turned by the robot's heading and placed at the distance of the expert goal it
    stands for, on the terrain: where a student that is right sees its goals exactly on the
    expert's.

    Args:
        goals_uni: (N, K, 2) the policy's output.
        pos: (N, 3) base positions; ``yaw`` (N,) headings, rad.
        goals: (N, G, 3) each robot's route (expert goals then P_B); ``goal_index`` (N,) the
            current goal; ``num_goals`` (N,) the route's length (P_B included).
        height_at: terrain height lookup, (M, 2) -> (M,).

    Returns:
        ``(directions (N, K, 2) unit world-frame xy, points (N, K, 3))``.
    """
    local = np.asarray(goals_uni, dtype=np.float64)
    local = local / np.maximum(np.linalg.norm(local, axis=-1, keepdims=True), 1e-6)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    world = np.stack([c * local[..., 0] - s * local[..., 1], s * local[..., 0] + c * local[..., 1]], axis=-1)
    n, k = world.shape[:2]
    idx = np.minimum(np.asarray(goal_index)[:, None] + np.arange(k)[None], np.asarray(num_goals)[:, None] - 1)
    dist = np.linalg.norm(np.asarray(goals)[np.arange(n)[:, None], idx, :2] - pos[:, None, :2], axis=-1)
    xy = pos[:, None, :2] + dist[..., None] * world
    z = np.asarray(height_at(xy.reshape(-1, 2))).reshape(n, k)
    return world, np.concatenate([xy, z[..., None]], axis=-1)


def _onnx_exists(path: Path) -> bool:
    """Whether ``path`` names an export: the file, or a student's pair beside it."""
    from legoh_rl.training.onnx_export import onnx_paths

    pair = onnx_paths(path)
    return path.is_file() or (pair["perception"].is_file() and pair["locomotion"].is_file())


def _count(name: str, value, low: int, high: int | None) -> int:
    """``value`` as an int in ``[low, high]`` (no upper bound for ``None``); ValueError naming it."""
    try:
        number = operator.index(value)
    except TypeError:
        number = None
    if number is None or isinstance(value, bool) or number < low or (high is not None and number > high):
        bound = f"an integer in [{low}, {high}]" if high is not None else f"an integer >= {low}"
        raise ValueError(f"{name} must be {bound}, got {value!r}")
    return number
