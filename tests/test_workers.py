"""Collection over K worker processes (legoh_rl/training/workers.py): slices, factories, pickling.

The end-to-end run with ``collector.workers=2`` is in tests/test_recipes.py.
"""

import pickle

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training.distill import DAggerMixture
from legoh_rl.training.workers import EnvSlice, check_workers, slice_config


def test_workers_must_divide_the_worlds():
    assert check_workers(1, 4) == 1 and check_workers(2, 4) == 2
    with pytest.raises(ValueError, match=r"collector.workers=3 must divide env.num_envs=4"):
        check_workers(3, 4)
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(ValueError, match=r"collector.workers must be a positive integer"):
            check_workers(bad, 4)


def test_a_slice_has_its_share_of_worlds_and_threads_and_its_own_seed():
    cfg = HikingEnvConfig(num_envs=8, num_threads=4, seed=10)
    parts = [slice_config(cfg, k, 2) for k in range(2)]
    assert [(p.num_envs, p.num_threads, p.seed) for p in parts] == [(4, 2, 10), (4, 2, 11)]
    assert slice_config(HikingEnvConfig(num_envs=8, num_threads=2), 3, 4).num_threads == 1  # at least one
    assert slice_config(cfg, 0, 1) == cfg  # one worker: the run's own env


def test_the_env_factory_is_picklable_and_builds_the_slice_on_the_runs_trails():
    cfg = HikingEnvConfig(num_envs=4, num_threads=1, categories=("randommix",), variants=1, seed=3)
    factory = pickle.loads(pickle.dumps(EnvSlice(cfg, 1, 2)))  # what a spawned worker receives
    env = factory()
    base = env.base_env
    assert env.batch_size == torch.Size([2]) and base.cfg.seed == 4 and base.cfg.num_threads == 1
    whole = HikingEnv(cfg)  # the terrain of the run's seed, not of seed + k
    assert np.array_equal(base.trails.tile_start, whole.trails.tile_start)
    td = env.reset()
    assert ("episode_reward" in td.keys()) and ("step_count" in td.keys())  # RewardSum, StepCounter
    env.close()
    whole.close()


class OnesTeacher:
    """A stand-in teacher: action 1 everywhere."""

    in_keys = ["obs"]

    def label(self, td):
        td.set("action_tea", torch.ones_like(td["obs"]))
        return td


def test_the_dagger_mixture_crosses_to_a_worker_with_its_coin_flips():
    student = TensorDictModule(torch.nn.Identity(), in_keys=["obs"], out_keys=["action"])
    mix = DAggerMixture(student, OnesTeacher(), seed=5)
    mix.set_schedule(0.5, False)
    copy = pickle.loads(pickle.dumps(mix))
    td = TensorDict({"obs": torch.zeros(64, 3)}, [64])
    assert copy.beta == 0.5 and torch.equal(copy(td.clone())["teacher_acted"], mix(td.clone())["teacher_acted"])
    mix.reseed(5)
    first = mix(td.clone())["teacher_acted"]
    mix.reseed(6)
    assert not torch.equal(mix(td.clone())["teacher_acted"], first)  # each worker its own stream
