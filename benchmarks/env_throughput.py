"""Control steps/s of the full HikingEnv vs the physics-only limit of the same worlds.

    python benchmarks/env_throughput.py [--seconds 5] [--repeats 1] [--warmup 100] [--threads 2] [--robots h1 g1]
        [--n 64 256] [--modes oracle student] [--march-samples S] [--backend auto|native|torch]

For each robot and N: oracle mode (no depth) and student mode (64x64 depth, cast every 5th
step), beside the physics-only limit measured in the same run (the same model and worlds
stepped with no observations, rewards or env resets; fallen worlds are put back on their spawn
pose, see ``physics_rate``), and the ratios. Actions are random (N(0, 0.5)), so worlds fall and
reset as in early training. Both measurements start after ``--warmup`` untimed steps from a full
reset, so that the timed window sees the steady rate of falls and resets rather than the calm
first second of standing robots. On a shared machine single measurements vary by +-20%;
``--repeats`` measures env and physics alternately that many times and reports the median of
each, the median of the per-pair ratios (each env window against the physics window right after
it, so drifting machine load hits both) and the range of those ratios. The last column, the share
of the env's timed window spent inside its own physics calls, estimates the same ratio from one
measurement (the same steps, so machine noise cancels); it leaves out the physics-only loop's
resets of fallen worlds, which the env counts as its overhead.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np
import torch

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.sensors import DepthCameraConfig


def env_rate(env: HikingEnv, seconds: float, warmup: int = 0) -> tuple[float, float]:
    """(env steps/s, the share of the timed wall time spent in the env's own physics calls)."""
    n = env.batch_size[0]
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    physics_s = [0.0]
    step = env.worlds.step

    def timed_step():
        t = time.perf_counter()
        out = step()
        physics_s[0] += time.perf_counter() - t
        return out

    env.worlds.step = timed_step
    try:
        for i in range(-warmup, 1 << 62):
            if i == 0:
                start, physics_s[0] = time.perf_counter(), 0.0
            elif i > 0 and time.perf_counter() - start >= seconds:
                wall = time.perf_counter() - start
                return i * n / wall, physics_s[0] / wall
            td["action"] = 0.5 * torch.randn(n, env.A, generator=gen)
            _, td = env.step_and_maybe_reset(td)
    finally:
        del env.worlds.step  # back to the class's method
    raise AssertionError("unreachable")


def physics_rate(env: HikingEnv, seconds: float, warmup: int = 0) -> float:
    """Physics alone on the env's worlds: random joint targets, and a world whose base drops
    half its standing height below its spawn height is put back on its spawn pose (a C call),
    as the env resets fallen worlds. Without that, every robot lies on the ground after a
    second or two, and contact-rich lying robots step slower than the env's mostly upright
    ones (G1 read env/physics ratios above 1)."""
    w = env.worlds
    rng = np.random.default_rng(0)
    q0 = env.q_default
    env.reset()
    spawn = w.home_qpos.copy()
    floor = spawn[:, 2] - 0.5 * env.robot.base_height_target
    for i in range(-warmup, 1 << 62):
        if i == 0:
            start = time.perf_counter()
        elif i > 0 and time.perf_counter() - start >= seconds:
            return i * w.num_worlds / (time.perf_counter() - start)
        w.set_joint_targets(q0 + 0.125 * rng.normal(size=(w.num_worlds, q0.size)))
        w.step()
        fallen = np.flatnonzero(w.qpos[:, 2] < floor)
        if fallen.size:
            w.reset(fallen, qpos=spawn[fallen])
    raise AssertionError("unreachable")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=5.0, help="length of one measurement")
    parser.add_argument("--repeats", type=int, default=1,
                        help="env and physics-only measured alternately this many times; medians reported")
    parser.add_argument("--warmup", type=int, default=100,
                        help="untimed control steps after the reset before each measurement")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--robots", nargs="+", default=["h1", "g1"])
    parser.add_argument("--n", nargs="+", type=int, default=[64, 256])
    parser.add_argument("--modes", nargs="+", default=["oracle", "student"], choices=["oracle", "student"])
    parser.add_argument("--march-samples", type=int, default=None, help="depth march samples (default: the config's)")
    parser.add_argument("--backend", choices=("auto", "native", "torch"), default="auto",
                        help="depth ray-march implementation (DepthCameraConfig.backend)")
    parser.add_argument("--profile", action="store_true", help="print the top functions of the student run")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{'robot':5} {'N':>4} {'mode':8} {'env steps/s':>12} {'physics-only':>13} {'ratio':>6} {'ratio range':>12} "
          f"{'physics share':>14}")
    for robot in args.robots:
        for n in args.n:
            for mode in args.modes:
                cam = DepthCameraConfig(backend=args.backend)
                if args.march_samples is not None:
                    cam.march_samples = args.march_samples
                cfg = HikingEnvConfig(robot=robot, num_envs=n, mode=mode, num_threads=args.threads, levels=(0, 1, 2),
                                      depth_camera=cam)
                env = HikingEnv(cfg)
                rates, shares, physs = [], [], []
                for _ in range(args.repeats):  # alternate, so that drifting machine load hits both columns
                    rate, share = env_rate(env, args.seconds, args.warmup)
                    rates.append(rate)
                    shares.append(share)
                    physs.append(physics_rate(env, args.seconds, args.warmup))
                rate, phys = float(np.median(rates)), float(np.median(physs))
                ratios = np.array(rates) / np.array(physs)
                if args.profile and mode == "student":
                    prof = cProfile.Profile()
                    prof.enable()
                    env_rate(env, args.seconds)
                    prof.disable()
                    pstats.Stats(prof).sort_stats("cumulative").print_stats(15)
                print(f"{robot:5} {n:4d} {mode:8} {rate:12.0f} {phys:13.0f} {np.median(ratios):6.2f} "
                      f"{ratios.min():6.2f}-{ratios.max():.2f} {np.median(shares):14.2f}", flush=True)


if __name__ == "__main__":
    main()
