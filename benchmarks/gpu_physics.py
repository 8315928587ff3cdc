"""Env steps/s with ``env.physics=warp`` (MuJoCo Warp on a device) beside ``env.physics=mujoco``.

    python benchmarks/gpu_physics.py --device cuda --n 1024 4096 8192 [--modes oracle student]
        [--seconds 10] [--warmup 20] [--threads 16]
    python benchmarks/gpu_physics.py --device cpu --n 4 --seconds 3     # Warp's CPU device: a check

For each mode and N, in one run: the full HikingEnv's steps/s on each backend (``env_rate`` of
``env_throughput.py``: random actions N(0, 0.5), so worlds fall and reset as in early training),
the Warp backend's physics-only steps/s (``WarpWorlds.step`` alone, the same worlds), and the
share of the Warp env's time spent in its host transfers (the upload of state and targets, the
download of outputs), which is what a device-resident env would remove. The C backend runs on
``--threads`` CPU threads.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from env_throughput import env_rate

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.warp_physics import WarpWorlds


def warp_physics_rate(worlds: WarpWorlds, seconds: float) -> float:
    """World-steps/s of ``worlds.step`` alone (fallen worlds put back on their home states)."""
    n, steps = worlds.num_worlds, 0
    rng = np.random.default_rng(0)
    q0 = np.array(worlds.built.robot.default_joint_pos)
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        worlds.set_joint_targets(q0 + 0.25 * rng.normal(size=(n, q0.size)))
        worlds.step()
        fallen = worlds.qpos[:, 2] < worlds.home_qpos[:, 2] - 0.4
        if fallen.any():
            worlds.reset(fallen, qpos=worlds.home_qpos[fallen])
        steps += 1
    return steps * n / (time.perf_counter() - start)


def transfer_share(env: HikingEnv, seconds: float) -> float:
    """Share of the Warp env's wall time spent in host <-> device transfers."""
    worlds = env.worlds
    spent = [0.0]
    originals = {name: getattr(worlds, name) for name in ("_upload_state", "_download")}

    def timed(fn):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            spent[0] += time.perf_counter() - t
            return out
        return wrapper

    for name, fn in originals.items():
        setattr(worlds, name, timed(fn))
    try:
        start = time.perf_counter()
        env_rate(env, seconds)
        return spent[0] / (time.perf_counter() - start)
    finally:
        for name in originals:
            delattr(worlds, name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--n", type=int, nargs="+", default=[1024, 4096, 8192])
    parser.add_argument("--modes", nargs="+", default=["oracle", "student"])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--robot", default="h1")
    args = parser.parse_args()
    torch.set_num_threads(args.threads or torch.get_num_threads())
    print(f"device={args.device} robot={args.robot} threads={torch.get_num_threads()}")
    print(f"{'mode':8} {'N':>6} {'mujoco env/s':>13} {'warp env/s':>11} {'warp physics/s':>15} "
          f"{'warp/mujoco':>12} {'transfers':>10}")
    for mode in args.modes:
        for n in args.n:
            rates = {}
            for physics in ("mujoco", "warp"):
                env = HikingEnv(HikingEnvConfig(robot=args.robot, num_envs=n, mode=mode, physics=physics,
                                                num_threads=args.threads,
                                                device=args.device if physics == "warp" else "cpu"))
                rates[physics], _ = env_rate(env, args.seconds, warmup=args.warmup)
                if physics == "warp":
                    share = transfer_share(env, min(args.seconds, 3.0))
                    physics_only = warp_physics_rate(env.worlds, args.seconds)
            print(f"{mode:8} {n:6d} {rates['mujoco']:13.0f} {rates['warp']:11.0f} {physics_only:15.0f} "
                  f"{rates['warp'] / rates['mujoco']:12.2f} {share:10.2f}", flush=True)


if __name__ == "__main__":
    main()
