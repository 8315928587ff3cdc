"""Is dt = 0.005 s x 4 stable for H1 and G1 in MuJoCo, or is 0.002 s x 10 needed?

    python benchmarks/timestep_stability.py [--worlds 64] [--steps 10000] [--robots h1 g1] [--dts 0.005 0.002]

Runs N worlds for the given number of 50 Hz control steps under random actions (uniform in
[-1, 1] x action scale around the default pose, redrawn every step, i.e. violent) on rough
ground, resetting fallen robots, and counts diverged worlds (non-finite state, MuJoCo
instability warnings), falls, and the largest joint speed seen.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from legoh_rl.envs.physics import BatchedWorlds
from legoh_rl.envs.robots import build_model
from legoh_rl.envs.rough_patch import RoughPatch


def run(robot: str, dt: float, decimation: int, worlds: int, steps: int, seed: int) -> dict:
    built = build_model(robot, terrain=RoughPatch(num_boxes=50, seed=seed), timestep=dt)
    sim = BatchedWorlds(built, worlds, decimation=decimation)
    rng = np.random.default_rng(seed)
    q0 = np.array(built.robot.default_joint_pos)
    falls, max_qvel = 0, 0.0
    start = time.perf_counter()
    for _ in range(steps):
        sim.set_joint_targets(q0 + built.robot.action_scale * rng.uniform(-1, 1, size=(worlds, q0.size)) * 4)
        sim.step()
        max_qvel = max(max_qvel, float(np.abs(sim.qvel[:, 6:]).max()))
        fallen = sim.qpos[:, 2] < 0.5 * built.robot.spawn_height
        if fallen.any():
            falls += int(fallen.sum())
            sim.reset(fallen)
    return {
        "robot": robot,
        "dt": dt,
        "decimation": decimation,
        "diverged": sim.diverged_total,
        "falls": falls,
        "max_joint_speed": max_qvel,
        "seconds": time.perf_counter() - start,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--steps", type=int, default=10000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robots", nargs="+", default=["h1", "g1"])
    parser.add_argument("--dts", nargs="+", type=float, default=[0.005, 0.002],
                        help="timesteps to try (0.005 with decimation 4, 0.002 with decimation 10)")
    args = parser.parse_args()
    for robot in args.robots:
        for dt in args.dts:
            dec = int(round(0.02 / dt))
            r = run(robot, dt, dec, args.worlds, args.steps, args.seed)
            print(
                f"{r['robot']} dt={r['dt']} x{r['decimation']}: {args.worlds} worlds x {args.steps} control steps, "
                f"diverged={r['diverged']} falls={r['falls']} max|dq|={r['max_joint_speed']:.1f} rad/s "
                f"({r['seconds']:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
