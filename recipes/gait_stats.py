"""How a policy walks: foot lift, airborne share and speed of its robots on one trail level.

    python recipes/gait_stats.py checkpoints/oracle_h1.pt                 # RandomMix level 0, 8 robots, 8 s
    python recipes/gait_stats.py checkpoints/student_h1.pt --level 1 --robots 16
    python recipes/gait_stats.py checkpoints/oracle_h1.pt --level 1 --categories randommix ditch hurdle gap forest

The policy acts deterministically on an evaluation env (no randomisation) built from the
checkpoint, as in ``recipes/evaluate.py``. After a 1 s settling period, every control step of
every robot still standing adds its two feet's height above the terrain under them (foot lift,
0 when the foot rests), whether each foot is off the ground, its horizontal speed, its torso's
tilt and its sideways position. A shuffling gait shows a p95 foot lift of a few cm; clearing 13 cm
logs needs more. Steps with both feet off the ground are a gait's flight phases (a leap over a gap
or a jump down); a walk has none. The sideways detour is how far a robot strays from the line it
started on (around trees, to a staggered stone).
"""

from __future__ import annotations

import numpy as np
import torch
from tqdm import tqdm

from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser


def gait_figures(contact: np.ndarray, lift: np.ndarray, vel_xy: np.ndarray, pos_xy: np.ndarray, roll: np.ndarray,
                 pitch: np.ndarray, walking: np.ndarray, dt: float) -> dict:
    """The gait figures of ``T`` control steps of ``N`` robots (each step ``dt`` s apart).

    Args:
        contact: (T, N, 2) bool, each foot on the ground; lift: (T, N, 2) foot height above the
            terrain under it (m, 0 at rest); vel_xy, pos_xy: (T, N, 2) base velocity (m/s) and
            position (m) in the world (the trails run along +x); roll, pitch: (T, N) rad;
            walking: (T, N) bool, the robot still walking at that step (not fallen or finished).

    Returns:
        over the walking steps: ``lift_mean``, ``lift_p95``, ``lift_max`` (m); ``airborne``, the
        share of foot-steps off the ground; ``flight``, the share of steps with both feet off
        (a leap or a jump); ``flight_max_s``, the longest such stretch of one robot (s);
        ``landed``, the share of steps in both-off stretches that end with a foot down and the
        robot still walking (a leap or a jump it landed: a fall into a pit also lifts both feet,
        and its stretch ends when the episode does, or with the window) and ``landed_max_s``, the
        longest of those;
        ``speed`` (m/s, mean horizontal); ``lean_deg``, the mean torso tilt from upright
        (``sqrt(roll^2 + pitch^2)``) and ``lean_p95_deg``; ``detour_m``, the mean over robots of the
        largest sideways (y) distance from where each robot was at the first step.
        NaN each when no step has a walking robot.
    """
    keys = ("lift_mean", "lift_p95", "lift_max", "airborne", "flight", "flight_max_s", "landed", "landed_max_s",
            "speed", "lean_deg", "lean_p95_deg", "detour_m")
    if not walking.any():
        return dict.fromkeys(keys, float("nan"))
    w = walking
    feet = lift[w]  # (M, 2)
    both_off = ~contact[..., 0] & ~contact[..., 1] & w  # (T, N)
    longest = longest_landed = landed_steps = 0
    for n in range(w.shape[1]):  # each robot's both-off stretches: the longest, and those it landed
        run = 0
        for t, off in enumerate(both_off[:, n]):
            if off:
                run += 1
                longest = max(longest, run)
                continue
            if run and w[t, n] and contact[t, n].any():  # a foot down with the robot still walking
                landed_steps += run
                longest_landed = max(longest_landed, run)
            run = 0
    tilt = np.degrees(np.sqrt(roll ** 2 + pitch ** 2))[w]
    side = np.where(w, np.abs(pos_xy[..., 1] - pos_xy[:1, :, 1]), np.nan)  # (T, N)
    return {
        "lift_mean": float(feet.mean()), "lift_p95": float(np.percentile(feet, 95)), "lift_max": float(feet.max()),
        "airborne": float((~contact[w]).mean()), "flight": float(both_off[w].mean()), "flight_max_s": longest * dt,
        "landed": landed_steps / int(w.sum()), "landed_max_s": longest_landed * dt,
        "speed": float(np.linalg.norm(vel_xy[w], axis=-1).mean()),
        "lean_deg": float(tilt.mean()), "lean_p95_deg": float(np.percentile(tilt, 95)),
        "detour_m": float(np.nanmean(np.nanmax(side, axis=0)[w.any(axis=0)])),
    }


def gait_stats(checkpoint: str, category: str = "randommix", level: int = 0, robots: int = 8, seconds: float = 8.0,
               seed: int = 0, settle_s: float = 1.0) -> dict:
    """Gait figures of ``checkpoint``'s policy (``"zero"``: hold the default pose) on one trail
    level: :func:`gait_figures` of every control step after ``settle_s``.

    Returns:
        ``{"robots", "standing" (robots not fallen or finished at the end), ...}`` with
        :func:`gait_figures`' figures.
    """
    if robots < 1 or seconds <= settle_s:
        raise ValueError(f"need robots >= 1 and seconds > settle_s ({settle_s}), got {robots}, {seconds}")
    env, policy, _, base = load_cell_policy(checkpoint, category, level, robots, seed)
    steps, settle = int(round(seconds / base.dt)), int(round(settle_s / base.dt))
    rec: dict[str, list] = {k: [] for k in ("contact", "lift", "vel_xy", "pos_xy", "roll", "pitch", "walking")}
    walking = np.ones(robots, bool)
    td = env.reset()
    with torch.no_grad():
        for k in tqdm(range(steps), desc="gait_stats", unit="steps", leave=False):
            td = env.step(policy(td))["next"]
            state = base.read_state()
            walking &= ~td["done"].numpy().reshape(-1)
            if k >= settle:
                for key, value in (("contact", state["contact"]), ("lift", state["foot_lift"]),
                                   ("vel_xy", state["lin_vel_w"][:, :2]), ("pos_xy", state["pos"][:, :2]),
                                   ("roll", state["roll"]), ("pitch", state["pitch"]), ("walking", walking)):
                    rec[key].append(np.array(value, copy=True))
    arrays = {k: np.stack(v) for k, v in rec.items()}
    return {"robots": robots, "standing": int(walking.sum()), **gait_figures(**arrays, dt=base.dt)}


def markdown_row(name: str, s: dict) -> str:
    """One table row of :func:`gait_stats`' figures (cm, %, s, deg, m)."""
    return (f"| {name} | {s['standing']} / {s['robots']} | {s['lift_p95'] * 100:.1f} | {s['airborne'] * 100:.0f} | "
            f"{s['flight'] * 100:.1f} | {s['flight_max_s']:.2f} | {s['landed'] * 100:.1f} | {s['landed_max_s']:.2f} | "
            f"{s['speed']:.2f} | {s['lean_deg']:.1f} | "
            f"{s['detour_m']:.2f} |")


TABLE_HEAD = ("| category | walking at the end | foot lift p95 (cm) | airborne per foot (%) | both feet off (%) | "
              "longest flight (s) | landed flights (%) | longest landed flight (s) | speed (m/s) | torso tilt (deg) | "
              "largest sideways detour (m) |\n"
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")


def main() -> None:
    parser = probe_parser(__doc__, seconds=8.0)
    parser.add_argument("--categories", nargs="+", default=None,
                        help="a table with a row per category (at --level) instead of one category's figures")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.categories:
        print(f"{args.checkpoint}, level {args.level}, {args.robots} robots, {args.seconds:g} s, seed {args.seed}\n")
        print(TABLE_HEAD)
        for category in args.categories:
            print(markdown_row(category, gait_stats(args.checkpoint, category, args.level, args.robots, args.seconds,
                                                    args.seed)))
        return
    s = gait_stats(args.checkpoint, args.category, args.level, args.robots, args.seconds, args.seed)
    print(f"{args.checkpoint} on {args.category} level {args.level}: {s['standing']} of {s['robots']} robots "
          f"still walking at {args.seconds:g} s")
    print(f"foot lift: mean {s['lift_mean'] * 100:.1f} cm, p95 {s['lift_p95'] * 100:.1f} cm, "
          f"max {s['lift_max'] * 100:.1f} cm; airborne share per foot {s['airborne']:.2f}; both feet off "
          f"{s['flight']:.3f} of the steps (longest {s['flight_max_s']:.2f} s), landed {s['landed']:.3f} (longest "
          f"{s['landed_max_s']:.2f} s); speed {s['speed']:.2f} m/s; "
          f"torso tilt {s['lean_deg']:.1f} deg (p95 {s['lean_p95_deg']:.1f}); largest sideways detour "
          f"{s['detour_m']:.2f} m")


if __name__ == "__main__":
    main()
