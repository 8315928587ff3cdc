"""Steps/s of Gymnasium's vector API on the batched env against the TorchRL env it wraps.

    python benchmarks/gym_vector.py [--n 64] [--seconds 1] [--repeats 15] [--warmup 100] [--threads 2]
        [--robot h1] [--mode oracle]

``gymnasium.make_vec("LegoH/Hike-<robot>-v0", num_envs=N, vectorization_mode="vector_entry_point")``
(:class:`~legoh_rl.envs.gym_env.HikingVectorEnv`: numpy actions in, numpy observations, rewards,
flags and infos out, finished worlds reset within the step) against the TorchRL env's
``step_and_maybe_reset`` loop (as in ``benchmarks/env_throughput.py``) on the very same
:class:`HikingEnv`: its worlds, levels 0-2 of all five categories, random N(0, 0.5) actions, so
worlds fall and reset as in early training. After one reset and ``--warmup`` untimed steps the two
loops take turns, ``--repeats`` windows of ``--seconds`` each, carrying on from the worlds' state
(no reset in between, so every window sees the steady rate of falls and resets). Short
alternating windows let machine load that drifts hit both loops alike: the table gives the
median rates and the median of the per-pair ratios (gym / torchrl) with their interquartile
range. Goal: ratio >= 0.8 at N = 64.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch

import legoh_rl.envs  # noqa: F401  (registers the ids)
from legoh_rl.envs import HikingEnv


class TorchRLLoop:
    """``step_and_maybe_reset`` with random N(0, 0.5) actions, resumable across windows."""

    def __init__(self, env: HikingEnv, seed: int = 0) -> None:
        self.env, self.td = env, env.reset()
        self.gen = torch.Generator().manual_seed(seed)

    def run(self, seconds: float) -> float:
        """World steps/s over one window of ``seconds``."""
        n, a = self.env.batch_size[0], self.env.A
        start, i = time.perf_counter(), 0
        while time.perf_counter() - start < seconds:
            self.td["action"] = 0.5 * torch.randn(n, a, generator=self.gen)
            _, self.td = self.env.step_and_maybe_reset(self.td)
            i += 1
        return i * n / (time.perf_counter() - start)


class GymLoop:
    """``envs.step`` with random N(0, 0.5) float32 numpy actions, resumable across windows."""

    def __init__(self, envs: gym.vector.VectorEnv, seed: int = 0) -> None:
        self.envs, self.rng = envs, np.random.default_rng(seed)

    def run(self, seconds: float) -> float:
        """World steps/s over one window of ``seconds``."""
        shape = self.envs.action_space.shape
        start, i = time.perf_counter(), 0
        while time.perf_counter() - start < seconds:
            self.envs.step((0.5 * self.rng.standard_normal(shape)).astype(np.float32))
            i += 1
        return i * self.envs.num_envs / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=64, help="worlds")
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one measurement window")
    parser.add_argument("--repeats", type=int, default=15, help="alternating window pairs")
    parser.add_argument("--warmup", type=int, default=100, help="untimed steps after the reset")
    parser.add_argument("--threads", type=int, default=2, help="physics threads")
    parser.add_argument("--robot", choices=("h1", "g1"), default="h1")
    parser.add_argument("--mode", choices=("oracle", "student"), default="oracle")
    args = parser.parse_args()
    torch.set_num_threads(1)
    env_id = f"LegoH/{'Hike' if args.mode == 'oracle' else 'HikeDepth'}-{args.robot.upper()}-v0"
    envs = gym.make_vec(env_id, num_envs=args.n, vectorization_mode="vector_entry_point",
                        num_threads=args.threads, levels=(0, 1, 2))
    hiking = envs.unwrapped.env  # the TorchRL env behind it: the same worlds for both loops
    torchrl_loop, gym_loop = TorchRLLoop(hiking), GymLoop(envs)
    envs.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(args.warmup):  # past the calm first second of standing robots
        envs.step((0.5 * rng.standard_normal(envs.action_space.shape)).astype(np.float32))
    torchrl_rates, gym_rates = [], []
    for i in range(args.repeats):  # alternate which loop goes first
        first, second = (torchrl_loop, gym_loop) if i % 2 == 0 else (gym_loop, torchrl_loop)
        r1, r2 = first.run(args.seconds), second.run(args.seconds)
        torchrl_rates.append(r1 if first is torchrl_loop else r2)
        gym_rates.append(r2 if first is torchrl_loop else r1)
    ratios = np.array(gym_rates) / np.array(torchrl_rates)
    q1, q3 = np.percentile(ratios, [25, 75])
    print(f"{'env':22} {'N':>4} {'mode':8} {'torchrl steps/s':>16} {'gym vector steps/s':>19} {'ratio':>6} "
          f"{'IQR':>10}")
    print(f"{env_id:22} {args.n:4d} {args.mode:8} {np.median(torchrl_rates):16.0f} {np.median(gym_rates):19.0f} "
          f"{np.median(ratios):6.2f} {q1:4.2f}-{q3:.2f}")
    envs.close()


if __name__ == "__main__":
    main()
