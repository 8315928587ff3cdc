"""`make demo`: the project's main job on embedded defaults (CPU, wandb offline).

Until the training recipes land, it is a smoke run of the batched physics: both robots, 64
worlds, 2 s of zero action (PD hold at the default pose) on rough ground with obstacles. It
prints the control-step throughput and when each robot falls (a pure PD hold does not balance a
humanoid: balancing is the policy's job).
"""

from __future__ import annotations

import time

import numpy as np

from legoh_rl.envs.physics import BatchedWorlds
from legoh_rl.envs.robots import build_model
from legoh_rl.envs.rough_patch import RoughPatch


def physics_smoke(robot: str, num_worlds: int = 64, seconds: float = 2.5) -> None:
    """Step ``num_worlds`` worlds of ``robot`` with the default-pose PD hold and report."""
    built = build_model(robot, terrain=RoughPatch(num_boxes=50))
    worlds = BatchedWorlds(built, num_worlds)
    rng = np.random.default_rng(0)
    qpos = np.tile(built.default_qpos, (num_worlds, 1))
    qpos[:, :2] = rng.uniform(-1.0, 1.0, size=(num_worlds, 2))  # spread the robots on the patch
    qpos[:, 2] += 0.1
    worlds.reset(qpos=qpos)
    targets = np.tile(np.array(built.robot.default_joint_pos), (num_worlds, 1))
    fall_time = np.full(num_worlds, np.nan)
    steps = int(seconds / worlds.dt)
    start = time.perf_counter()
    for k in range(steps):
        worlds.set_joint_targets(targets)
        worlds.step()
        fallen = np.isnan(fall_time) & (worlds.qpos[:, 2] < 0.6 * built.robot.spawn_height)
        fall_time[fallen] = (k + 1) * worlds.dt
    elapsed = time.perf_counter() - start
    print(
        f"[{robot}] {num_worlds} worlds x {steps} control steps ({worlds.dt * 1000:.0f} ms each) in "
        f"{elapsed:.2f} s = {num_worlds * steps / elapsed:,.0f} control steps/s on "
        f"{worlds.num_threads} threads; diverged worlds: {worlds.diverged_total}"
    )
    fell = ~np.isnan(fall_time)
    print(
        f"[{robot}] PD hold, zero action: {fell.sum()}/{num_worlds} robots fell within {seconds} s"
        + (f", median time to fall {np.nanmedian(fall_time):.2f} s" if fell.any() else "")
    )


def main() -> None:
    print("legoh-rl demo: batched MuJoCo physics smoke (training recipes: see README)")
    for robot in ("h1", "g1"):
        physics_smoke(robot)


if __name__ == "__main__":
    main()
