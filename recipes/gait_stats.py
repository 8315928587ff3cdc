"""How a policy walks: foot lift, airborne share and speed of its robots on one trail level.

    python recipes/gait_stats.py checkpoints/oracle_h1.pt                 # RandomMix level 0, 8 robots, 8 s
    python recipes/gait_stats.py checkpoints/student_h1.pt --level 1 --robots 16

The policy acts deterministically on an evaluation env (no randomisation) built from the
checkpoint, as in ``recipes/evaluate.py``. After a 1 s settling period, every control step of
every robot still standing adds its two feet's height above the terrain under them (foot lift,
0 when the foot rests), whether each foot is off the ground, and its horizontal speed. A
shuffling gait shows a p95 foot lift of a few cm; clearing 13 cm logs needs more.
"""

from __future__ import annotations

import numpy as np
import torch
from tqdm import tqdm

from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser


def gait_stats(checkpoint: str, category: str = "randommix", level: int = 0, robots: int = 8, seconds: float = 8.0,
               seed: int = 0, settle_s: float = 1.0) -> dict:
    """Gait figures of ``checkpoint``'s policy (``"zero"``: hold the default pose).

    Returns:
        ``{"robots", "standing" (robots not fallen or finished at the end), "lift_mean",
        "lift_p95", "lift_max" (m), "airborne" (share of foot-steps off the ground), "speed"
        (m/s, mean horizontal base speed)}``, averaged over the robots still walking.
    """
    if robots < 1 or seconds <= settle_s:
        raise ValueError(f"need robots >= 1 and seconds > settle_s ({settle_s}), got {robots}, {seconds}")
    env, policy, _, base = load_cell_policy(checkpoint, category, level, robots, seed)
    steps, settle = int(round(seconds / base.dt)), int(round(settle_s / base.dt))
    lifts, air, speed = [], [], []
    walking = np.ones(robots, bool)
    td = env.reset()
    with torch.no_grad():
        for k in tqdm(range(steps), desc="gait_stats", unit="steps", leave=False):
            td = env.step(policy(td))["next"]
            state = base.read_state()
            walking &= ~td["done"].numpy().reshape(-1)
            if k >= settle:
                lifts.append(np.where(walking[:, None], state["foot_lift"], np.nan))
                air.append(np.where(walking[:, None], ~state["contact"], np.nan))
                speed.append(np.where(walking, np.linalg.norm(state["lin_vel_w"][:, :2], axis=1), np.nan))
    lift, airborne = np.array(lifts), np.array(air, dtype=float)
    if np.isnan(lift).all():
        return {"robots": robots, "standing": 0, **dict.fromkeys(("lift_mean", "lift_p95", "lift_max", "airborne",
                                                                 "speed"), float("nan"))}
    return {
        "robots": robots, "standing": int(walking.sum()),
        "lift_mean": float(np.nanmean(lift)), "lift_p95": float(np.nanpercentile(lift, 95)),
        "lift_max": float(np.nanmax(lift)), "airborne": float(np.nanmean(airborne)), "speed": float(np.nanmean(speed)),
    }


def main() -> None:
    args = probe_parser(__doc__, seconds=8.0).parse_args()
    torch.set_num_threads(1)
    s = gait_stats(args.checkpoint, args.category, args.level, args.robots, args.seconds, args.seed)
    print(f"{args.checkpoint} on {args.category} level {args.level}: {s['standing']} of {s['robots']} robots "
          f"still walking at {args.seconds:g} s")
    print(f"foot lift: mean {s['lift_mean'] * 100:.1f} cm, p95 {s['lift_p95'] * 100:.1f} cm, "
          f"max {s['lift_max'] * 100:.1f} cm; airborne share per foot {s['airborne']:.2f}; speed {s['speed']:.2f} m/s")


if __name__ == "__main__":
    main()
