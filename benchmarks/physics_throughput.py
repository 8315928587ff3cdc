"""Physics throughput of the batched worlds: physics steps/s and control steps/s.

    python benchmarks/physics_throughput.py [--seconds 3] [--threads 2]

For h1 and g1, on flat ground and on a rough heightfield with 50 box obstacles, N in {1, 64, 256}.
The robots get random leg targets around the default pose and fallen worlds are reset, so the
figures include contact-rich and falling states.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from legoh_rl.envs.physics import BatchedWorlds
from legoh_rl.envs.robots import build_model
from legoh_rl.envs.rough_patch import RoughPatch


def measure(robot: str, terrain, n: int, seconds: float, threads: int, decimation: int, dt: float) -> tuple[float, float]:
    built = build_model(robot, terrain=terrain, timestep=dt)
    worlds = BatchedWorlds(built, n, decimation=decimation, num_threads=threads)
    rng = np.random.default_rng(0)
    q0 = np.array(built.robot.default_joint_pos)
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        worlds.set_joint_targets(q0 + 0.25 * rng.normal(size=(n, q0.size)))
        worlds.step()
        fallen = worlds.qpos[:, 2] < 0.5 * built.robot.spawn_height
        if fallen.any():
            worlds.reset(fallen)
        steps += 1
    elapsed = time.perf_counter() - start
    control = steps * n / elapsed
    return control * decimation, control


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--decimation", type=int, default=4)
    parser.add_argument("--dt", type=float, default=0.005)
    args = parser.parse_args()
    print(f"dt={args.dt} decimation={args.decimation} threads={args.threads}")
    print(f"{'robot':5} {'terrain':6} {'N':>4} {'physics steps/s':>16} {'control steps/s':>16}")
    for robot in ("h1", "g1"):
        for tname, terrain in (("flat", None), ("rough", RoughPatch(num_boxes=50))):
            for n in (1, 64, 256):
                phys, ctrl = measure(robot, terrain, n, args.seconds, args.threads, args.decimation, args.dt)
                print(f"{robot:5} {tname:6} {n:4d} {phys:16.0f} {ctrl:16.0f}", flush=True)


if __name__ == "__main__":
    main()
