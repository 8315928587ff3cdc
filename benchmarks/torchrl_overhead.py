"""torchrl's own cost per control step for HikingEnv's output layout, without the env's work.

    python benchmarks/torchrl_overhead.py [--n 64] [--steps 2000] [--repeats 3]

A stand-in env with HikingEnv's specs (oracle mode, H1) whose ``_step``/``_reset`` wrap
prebuilt tensors in a new TensorDict each call (as ``HikingEnv._to_td`` does, without the numpy
work), with a partial reset on 52% of the steps as under random actions, is run through
``step_and_maybe_reset``: what is left is torchrl's step, ``step_mdp`` and reset merging. The same
with the nested observation groups (``episode``, ``info``) flattened into root keys shows what the
nesting costs. (The ``reward_terms`` are reward entries: in ``"next"`` only.)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import Composite
from torchrl.envs import EnvBase

from legoh_rl.envs import HikingEnv, HikingEnvConfig


def _flat(spec: Composite, prefix: str = "") -> dict:
    out = {}
    for key, value in spec.items():
        if isinstance(value, Composite):
            out.update(_flat(value, f"{prefix}{key}_"))
        else:
            out[prefix + key] = value
    return out


class CachedOutputEnv(EnvBase):
    """HikingEnv's specs (nested, or flattened); every step returns the same output, cloned."""

    batch_locked = True

    def __init__(self, real: HikingEnv, flat: bool, reset_share: float = 0.52, seed: int = 0) -> None:
        n = real.batch_size[0]
        super().__init__(batch_size=torch.Size([n]))
        obs = real.observation_spec.clone()
        self.observation_spec = Composite(_flat(obs), shape=(n,)) if flat else obs
        self.action_spec = real.action_spec.clone()
        self.reward_spec = real.full_reward_spec.clone()  # reward and ("reward_terms", name)
        self.done_spec = real.done_spec.clone()
        out = self.full_observation_spec.zero()
        out.update(self.full_done_spec.zero())
        self._reset_out = out.to_dict()
        out.update(self.full_reward_spec.zero())
        self._step_out = out.to_dict()
        self._rng = np.random.default_rng(seed)
        self._share = reset_share

    def _step(self, tensordict):
        out = TensorDict._new_unsafe(self._step_out, batch_size=self.batch_size)
        done = torch.zeros(self.batch_size[0], 1, dtype=torch.bool)
        if self._rng.random() < self._share:
            done[self._rng.integers(self.batch_size[0])] = True
        out["done"], out["terminated"] = done, done.clone()
        return out

    def _reset(self, tensordict=None, **kwargs):
        return TensorDict._new_unsafe(self._reset_out, batch_size=self.batch_size)

    def _set_seed(self, seed):
        self._rng = np.random.default_rng(seed)


def per_step_ms(env: EnvBase, steps: int, action_dim: int) -> float:
    n = env.batch_size[0]
    td = env.reset()
    for _ in range(100):
        td["action"] = torch.zeros(n, action_dim)
        _, td = env.step_and_maybe_reset(td)
    start = time.perf_counter()
    for _ in range(steps):
        td["action"] = torch.zeros(n, action_dim)
        _, td = env.step_and_maybe_reset(td)
    return (time.perf_counter() - start) / steps * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3, help="alternate the two layouts this many times")
    args = parser.parse_args()
    torch.set_num_threads(1)
    real = HikingEnv(HikingEnvConfig(robot="h1", num_envs=args.n, mode="oracle", num_threads=1, levels=(0,)))
    envs = {"nested (HikingEnv's keys)": CachedOutputEnv(real, flat=False),
            "flattened": CachedOutputEnv(real, flat=True)}
    times = {name: [] for name in envs}
    for _ in range(args.repeats):
        for name, env in envs.items():
            times[name].append(per_step_ms(env, args.steps, real.A))
    keys = {name: len(list(env.full_observation_spec.keys(True, True))) for name, env in envs.items()}
    for name, ts in times.items():
        print(f"{name:26s} {keys[name]:3d} observation leaves: {np.median(ts):.2f} ms per step "
              f"(runs {', '.join(f'{t:.2f}' for t in ts)})")


if __name__ == "__main__":
    main()
