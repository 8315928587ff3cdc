"""Env steps/s of collection with K worker processes (``collector.workers``), K = 1, 2, ... in one run.

    python benchmarks/collector_workers.py [--workers 1 2] [--n 64] [--threads 2] [--steps-per-env 24]
        [--batches 4] [--repeats 3] [--mode oracle|student] [--robot h1] [--layers 512 256 128]

What the training loop does between two updates, and nothing else: K = 1 is torchrl's ``Collector``
on one ``HikingEnv`` of N worlds with ``--threads`` physics threads (``collector.workers=1``);
K > 1 is the ``MultiSyncCollector`` of :mod:`legoh_rl.training.workers`, K processes of N / K
worlds with ``--threads / K`` physics threads each (at least 1), the slices' batches concatenated
into the same ``[N, T]`` batch. The policy is the oracle actor (random weights, sampling), torch on
one thread per process; the env is in oracle mode (``--mode student`` adds the 64x64 depth camera
and the student's transforms are left out: the policy is the oracle's). Levels 0-2 of all five
categories, so robots fall and reset as in early training.

All collectors are built first (a worker process takes seconds to start: spawned, it imports
torch and MuJoCo and builds its worlds) and each collects one untimed batch. Then each repeat
times ``--batches`` batches of every K in turn, so drifting machine load hits them alike; the
table gives the median rate of each K and the median and range of its per-repeat ratio to K = 1.
Note the other load on the machine with the figures: a worker process needs a core of its own.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import ExplorationType

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training.builders import make_oracle
from legoh_rl.training.workers import make_worker_collector


def make_collector(cfg: HikingEnvConfig, workers: int, frames_per_batch: int, layers: tuple[int, ...]):
    """The collector of K = ``workers`` processes, ``frames_per_batch`` frames a batch, running the
    oracle actor of MLP widths ``layers``."""
    env = HikingEnv(cfg)
    _, actor, _ = make_oracle(env, 1.0, layers)
    kwargs = dict(exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
    if workers == 1:
        collector = Collector(TransformedEnv(env, Compose(RewardSum(), StepCounter())), actor,
                              frames_per_batch=frames_per_batch, total_frames=-1, **kwargs)
    else:
        collector = make_worker_collector(cfg, workers, None, actor, frames_per_batch, -1, 1, **kwargs)
        env.close()  # the main process's copy only sized the networks
    return collector


def timed(it, batches: int) -> float:
    """Frames/s over ``batches`` batches of an iterator over a collector."""
    start, frames = time.perf_counter(), 0
    for _ in range(batches):
        frames += next(it).numel()
    return frames / (time.perf_counter() - start)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--n", type=int, default=64, help="worlds in all (each worker steps n / K)")
    p.add_argument("--threads", type=int, default=2, help="physics threads in all (each worker threads / K)")
    p.add_argument("--steps-per-env", type=int, default=24)
    p.add_argument("--batches", type=int, default=4, help="timed batches per K and repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--mode", choices=("oracle", "student"), default="oracle")
    p.add_argument("--robot", default="h1")
    p.add_argument("--layers", type=int, nargs="+", default=[512, 256, 128])
    args = p.parse_args()
    if 1 not in args.workers:
        args.workers = [1, *args.workers]
    torch.set_num_threads(1)
    cfg = HikingEnvConfig(robot=args.robot, num_envs=args.n, mode="student" if args.mode == "student" else "oracle",
                          levels=(0, 1, 2), num_threads=args.threads)
    frames = args.n * args.steps_per_env
    collectors, iters = {}, {}
    try:
        for k in args.workers:
            start = time.perf_counter()
            collectors[k] = make_collector(cfg, k, frames, tuple(args.layers))
            iters[k] = iter(collectors[k])
            next(iters[k])  # untimed: the first batch resets every world
            print(f"K={k}: built and warmed up in {time.perf_counter() - start:.1f} s", flush=True)
        rates: dict[int, list[float]] = {k: [] for k in args.workers}
        for r in range(args.repeats):
            for k in args.workers:
                rates[k].append(timed(iters[k], args.batches))
            print(f"repeat {r + 1}: " + ", ".join(f"K={k} {rates[k][-1]:,.0f}" for k in args.workers), flush=True)
    finally:
        for c in collectors.values():
            c.shutdown()
    load = os.getloadavg()[0]
    print(f"\n{args.robot} {args.mode}, N = {args.n}, T = {args.steps_per_env} ({frames} frames a batch), "
          f"{args.threads} physics threads in all, {os.cpu_count()} CPUs, load average {load:.1f} at the end\n")
    print("| K | worlds per worker | physics threads per worker | env steps/s | ratio to K = 1 | range |")
    print("|---:|---:|---:|---:|---:|---|")
    for k in args.workers:
        ratios = [a / b for a, b in zip(rates[k], rates[1], strict=True)]
        print(f"| {k} | {args.n // k} | {max(1, args.threads // k)} | {statistics.median(rates[k]):,.0f} | "
              f"{statistics.median(ratios):.2f} | {min(ratios):.2f}-{max(ratios):.2f} |")


if __name__ == "__main__":
    main()
