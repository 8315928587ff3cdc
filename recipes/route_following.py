"""How well a policy keeps to the trail's route: heading errors and distance from the route over time.

    python recipes/route_following.py checkpoints/oracle_h1.pt              # RandomMix level 0, 8 robots
    python recipes/route_following.py checkpoints/student_h1.pt --level 1

The policy acts deterministically on an evaluation env (no randomisation, no spawn jitter) built
from the checkpoint, as in ``recipes/evaluate.py``. At every control step of every robot still
on its first episode it records:

* the signed yaw of its current expert goal in its heading frame (``expert_goals`` row 0;
  positive: the goal lies to the left), and of the trail end P_B (``goal_gps``);
* the signed angle from that goal to the direction the base moves in (course error; positive:
  it moves to the left of the goal; NaN below 0.1 m/s), which differs from the goal's yaw when
  the robot walks with its torso turned;
* for a student, the signed yaw of its own predicted next goal (``goals_uni`` row 0) and the
  angle between that prediction and the expert goal;
* its distance from the route, the polyline P_A -> expert goals -> P_B.

``--goal-source expert`` (students only) feeds the locomotion module the expert goal in place
of its own predicted one (``goal_next``), which separates navigation errors (the predicted
goal points the wrong way) from steering errors (the robot does not turn towards its goal).

A policy that follows the route keeps all of these near 0. Trail Completion (docs/metrics.md)
counts expert goals passed within 0.5 m, so a route offset above 0.5 m costs TC even when the
robot reaches P_B. The table is printed in time bins (median over robots and steps, and the
mean of the signed yaws, which shows a steady bias to one side).
"""

from __future__ import annotations

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.envs.sensors import world_to_yaw_frame, yaw_from_quat
from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser, with_expert_goal

COLUMNS = ("expert_yaw", "course_error", "end_yaw", "pred_yaw", "pred_error", "route_offset")


def signed_yaw_deg(vec: np.ndarray) -> np.ndarray:
    """(...,) signed angle of (..., 2) vectors (x forward, y left) in degrees, in (-180, 180]."""
    return np.degrees(np.arctan2(vec[..., 1], vec[..., 0]))


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) unsigned angle between (..., 2) vectors in degrees, in [0, 180]."""
    d = np.abs(signed_yaw_deg(a) - signed_yaw_deg(b))
    return np.minimum(d, 360.0 - d)


def course_error_deg(goal_yaw_frame: np.ndarray, vel_world: np.ndarray, yaw: np.ndarray,
                     min_speed: float = 0.1) -> np.ndarray:
    """(N,) signed angle (deg) from the goal direction to the horizontal velocity.

    Args:
        goal_yaw_frame: (N, 2) goal direction in the robot's yaw frame.
        vel_world: (N, 2) horizontal base velocity, world frame, m/s.
        yaw: (N,) the robot's heading, rad.
        min_speed: below this speed the course is undefined (NaN).
    """
    vel = world_to_yaw_frame(vel_world, yaw)
    d = signed_yaw_deg(vel) - signed_yaw_deg(goal_yaw_frame)
    d = (d + 180.0) % 360.0 - 180.0
    return np.where(np.linalg.norm(vel_world, axis=-1) >= min_speed, d, np.nan)


def distance_to_polyline(xy: np.ndarray, points: np.ndarray, count: np.ndarray) -> np.ndarray:
    """(N,) distance of each point ``xy`` (N, 2) from its polyline ``points[i, :count[i]]``.

    Args:
        xy: (N, 2) query points.
        points: (N, K, 2) polyline vertices; rows past ``count[i]`` are ignored.
        count: (N,) number of vertices of each polyline (>= 1).
    """
    a, b = points[:, :-1], points[:, 1:]  # (N, K-1, 2) segments
    ab = b - a
    t = np.einsum("nkd,nkd->nk", xy[:, None] - a, ab) / np.maximum(np.einsum("nkd,nkd->nk", ab, ab), 1e-12)
    nearest = a + np.clip(t, 0.0, 1.0)[..., None] * ab
    dist = np.linalg.norm(xy[:, None] - nearest, axis=-1)
    valid = np.arange(points.shape[1] - 1)[None] < (count[:, None] - 1)
    single = np.linalg.norm(xy - points[:, 0], axis=-1)  # a one-vertex polyline is a point
    return np.where(count > 1, np.where(valid, dist, np.inf).min(axis=1, initial=np.inf), single)


def route_following(checkpoint: str, category: str = "randommix", level: int = 0, robots: int = 8,
                    seconds: float = 30.0, seed: int = 0, variants: int = 8,
                    goal_source: str = "predicted") -> dict[str, np.ndarray]:
    """Per-step route figures of ``checkpoint``'s policy (``"zero"``: hold the default pose).

    Returns:
        ``{"time": (T,) s, "expert_yaw", "course_error", "end_yaw", "pred_yaw": (T, robots) signed degrees,
        "pred_error": (T, robots) degrees, "route_offset": (T, robots) m}``; NaN once a robot's
        first episode has ended, and ``pred_*`` all NaN for a policy without ``goals_uni``
        (the oracle). ``goal_source="expert"`` gives a student's locomotion module the current
        expert goal as ``goal_next`` (the predicted goals are still recorded).

    Raises:
        ValueError: bad ``robots``/``seconds``, an unknown ``goal_source``, or ``"expert"`` for a
            policy that is not a student.
    """
    if robots < 1 or seconds <= 0:
        raise ValueError(f"need robots >= 1 and seconds > 0, got robots={robots}, seconds={seconds}")
    if goal_source not in ("predicted", "expert"):
        raise ValueError(f"goal_source must be 'predicted' or 'expert', got {goal_source!r}")
    env, policy, kind, base = load_cell_policy(checkpoint, category, level, robots, seed, variants)
    if goal_source == "expert":
        policy = with_expert_goal(policy, kind)
    env.set_seed(seed)
    base.assign_tiles(np.full(robots, level), np.full(robots, base.trails.categories.index(category)))
    td = env.reset()
    route = np.concatenate([base.start[:, None, :2], base.goals[:, :, :2]], axis=1)
    vertices = base.num_goals + 1
    rows = {k: [] for k in COLUMNS}
    ended = np.zeros(robots, bool)
    steps = min(int(round(seconds / base.dt)), base.max_steps)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in tqdm(range(steps), desc="route_following", unit="steps", leave=False):
            td = policy(td)
            expert = td["expert_goals"].numpy()[:, 0]
            pred = td["goals_uni"].numpy()[:, 0] if "goals_uni" in td.keys() else np.full_like(expert, np.nan)
            values = {
                "expert_yaw": signed_yaw_deg(expert),
                "course_error": course_error_deg(expert, base.worlds.qvel[:, :2],
                                                 yaw_from_quat(base.worlds.qpos[:, 3:7])),
                "end_yaw": signed_yaw_deg(td["goal_gps"].numpy()),
                "pred_yaw": signed_yaw_deg(pred), "pred_error": angle_between_deg(pred, expert),
                "route_offset": distance_to_polyline(base.worlds.qpos[:, :2], route, vertices),
            }
            for k, v in values.items():
                rows[k].append(np.where(ended, np.nan, v))
            out, td = env.step_and_maybe_reset(td)
            ended |= out["next", "done"].reshape(-1).numpy()
            if ended.all():
                break
    result = {k: np.array(v) for k, v in rows.items()}
    result["time"] = np.arange(len(rows["expert_yaw"])) * base.dt
    return result


def summary_table(result: dict[str, np.ndarray], bin_s: float = 2.0) -> str:
    """A markdown table of ``result`` in time bins: |median| and mean of the signed yaws (deg),
    median prediction error (deg) and median / max route offset (m)."""
    lines = ["| time (s) | robots | expert goal yaw: median abs / mean | course error: median abs / mean "
             "| P_B yaw: median abs / mean | predicted goal yaw: median abs / mean | prediction error | route offset: median / max |",
             "|---|---:|---|---|---|---|---:|---|"]
    t = result["time"]
    edges = np.arange(0.0, t[-1] + bin_s, bin_s) if t.size else np.array([0.0])
    for lo in edges:
        sel = (t >= lo) & (t < lo + bin_s)
        if not sel.any():
            continue
        alive = int(np.isfinite(result["route_offset"][sel][0]).sum())
        if alive == 0:
            continue
        err = result["pred_error"][sel]
        err_s = "-" if np.isnan(err).all() else f"{np.nanmedian(err):.0f}"
        off = result["route_offset"][sel]
        yaws = " | ".join(_yaw_pair(result[k][sel]) for k in ("expert_yaw", "course_error", "end_yaw", "pred_yaw"))
        lines.append(f"| {lo:.0f}-{lo + bin_s:.0f} | {alive} | {yaws} | {err_s} | {np.nanmedian(off):.2f} / {np.nanmax(off):.2f} |")
    return "\n".join(lines)


def _yaw_pair(v: np.ndarray) -> str:
    """'median |v| / mean v' of signed yaws, or '-' when all are NaN."""
    if np.isnan(v).all():
        return "-"
    return f"{np.nanmedian(np.abs(v)):.0f} / {np.nanmean(v):+.0f}"


def main() -> None:
    parser = probe_parser(__doc__, seconds=30.0)
    parser.add_argument("--variants", type=int, default=8)
    parser.add_argument("--goal-source", default="predicted", choices=("predicted", "expert"),
                        help="students: the goal the locomotion module gets (its own prediction or the expert's)")
    parser.add_argument("--bin", type=float, default=2.0, help="time bin of the table, s")
    args = parser.parse_args()
    torch.set_num_threads(1)
    result = route_following(args.checkpoint, args.category, args.level, args.robots, args.seconds, args.seed,
                             args.variants, args.goal_source)
    print(f"{args.checkpoint} on {args.category} level {args.level} (seed {args.seed}, {args.robots} robots, "
          f"{args.goal_source} goal); "
          "yaws in degrees, positive = to the left of the heading")
    print(summary_table(result, args.bin))
    offset = result["route_offset"][np.isfinite(result["route_offset"])]
    print(f"over the run: median route offset {np.median(offset):.2f} m, share of robot-steps more than 0.5 m "
          f"off the route {np.mean(offset > 0.5) * 100:.0f}%")


if __name__ == "__main__":
    main()
