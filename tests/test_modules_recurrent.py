"""Recurrent state of the perception networks: per-world resets, recurrent mode, Collector."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import Composite, Unbounded
from torchrl.envs import EnvBase, InitTracker, TransformedEnv
from torchrl.modules import set_recurrent_mode
from torchrl.modules.utils import get_primers_from_module

from legoh_rl.modules import (
    LocomotionConfig,
    make_locomotion_actor,
    make_perception,
    perception_config,
)

PROPRIO = 37
OUTS = ("z_uni", "delta_g0", "goals_uni")
STATE_KEYS = {
    "tcvit": ("perception_hidden",),
    "tcvit_ct": ("perception_context", "perception_context_valid"),
}


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """Tiny batches: one intra-op thread avoids OpenMP stalls on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def cfg():
    return perception_config("cpu", proprio_dim=PROPRIO)


def random_obs(cfg, n, g):
    io = cfg.io
    h = io.image_size
    return TensorDict(
        {
            "depth_goal_stack": torch.rand(n, io.num_frames, io.stack_channels, h, h, generator=g),
            "depth": torch.rand(n, 1, h, h, generator=g),
            "goal_gps": torch.randn(n, 2, generator=g),
            "waypoint_gps": torch.randn(n, 2, generator=g),
            "proprio": torch.randn(n, io.proprio_dim, generator=g),
        },
        batch_size=[n],
    )


def corrupt_later_states(data, name):
    """Overwrite the stored memory of every step after the first that is not an episode
    start: recurrent mode must read the state at t = 0 (and the primer's zeros at resets)
    and rebuild the rest itself."""
    data = data.clone()
    g = torch.Generator().manual_seed(123)
    keep = data["is_init"].clone()
    keep[:, 0] = True
    for key in STATE_KEYS[name]:
        value = data[key]
        noise = torch.randn(value.shape, generator=g)
        noise = noise > 0 if value.dtype == torch.bool else noise
        mask = keep.view(*keep.shape[:2], *([1] * (value.dim() - 2)))
        data[key] = torch.where(mask, value, noise)
    return data


def step_through(net, name, obs_steps, is_init_steps):
    """Run ``net`` one step at a time like a Collector; return the stacked [N, T] data."""
    n = obs_steps[0].batch_size[0]
    primers = get_primers_from_module(net).primers  # the env primer's zero-filled state
    state = TensorDict({k: primers[k].zero().expand(n, *primers[k].shape).clone()
                        for k in STATE_KEYS[name]}, batch_size=[n])
    records = []
    for obs, is_init in zip(obs_steps, is_init_steps, strict=True):
        td = obs.clone()
        td["is_init"] = is_init
        for key in STATE_KEYS[name]:
            value = state[key]
            # what the env primer does at a reset: zero the state of the reset worlds
            mask = is_init.view(-1, *([1] * (value.dim() - 1)))
            td[key] = torch.where(mask, torch.zeros_like(value), value)
        td = net(td)
        state = td["next"].clone()
        records.append(td)
    return torch.stack(records, dim=1)


@pytest.mark.parametrize("name", ["tcvit", "tcvit_ct"])
def test_reset_is_per_world(cfg, name):
    torch.manual_seed(0)
    net = make_perception(name, cfg).eval()
    g = torch.Generator().manual_seed(0)
    obs = [random_obs(cfg, 2, g) for _ in range(4)]
    init = [torch.tensor([[True], [True]])] + [torch.tensor([[False], [False]])] * 2
    init.append(torch.tensor([[True], [False]]))  # world 0 restarts at step 3
    with torch.no_grad():
        data = step_through(net, name, obs, init)
        last = data[:, -1]
        # world 0 equals a fresh start on the same observation
        fresh = obs[-1][:1].clone()
        fresh["is_init"] = torch.tensor([[True]])
        fresh = net(fresh)
        # world 1 equals continuing from its own state, and differs from a fresh start
        cont = obs[-1][1:].clone()
        cont["is_init"] = torch.tensor([[False]])
        for key in STATE_KEYS[name]:
            cont[key] = data[1:, -2]["next", key]
        cont = net(cont)
        restart1 = obs[-1][1:].clone()
        restart1["is_init"] = torch.tensor([[True]])
        restart1 = net(restart1)
    for key in OUTS:
        torch.testing.assert_close(last[key][:1], fresh[key])
        torch.testing.assert_close(last[key][1:], cont[key])
    assert not torch.allclose(last["z_uni"][1:], restart1["z_uni"], atol=1e-4)
    for key in STATE_KEYS[name]:
        torch.testing.assert_close(last["next", key][:1], fresh["next", key])


@pytest.mark.parametrize("name", ["tcvit", "tcvit_ct"])
def test_recurrent_mode_matches_stepping(cfg, name):
    torch.manual_seed(0)
    net = make_perception(name, cfg).eval()
    g = torch.Generator().manual_seed(1)
    steps = 12 if name == "tcvit_ct" else 6  # longer than the CT window (8)
    obs = [random_obs(cfg, 2, g) for _ in range(steps)]
    init = [torch.tensor([[True], [True]])] + [torch.tensor([[False], [False]])] * (steps - 1)
    init[3] = torch.tensor([[True], [False]])  # a reset in the middle of world 0's sequence
    with torch.no_grad():
        data = step_through(net, name, obs, init)
        # replay from step 2 on: the state stored at the first step carries the past
        replay = data[:, 2:].exclude("next", *OUTS, "perception_features",
                                     "perception_memory_in", "perception_memory_out")
        replay = corrupt_later_states(replay, name)
        stepwise = net(replay.clone())  # sanity: the corrupted states do matter step-wise
        with set_recurrent_mode(True):
            replay = net(replay)
    assert not torch.allclose(stepwise["z_uni"], data[:, 2:]["z_uni"], atol=1e-3)
    for key in OUTS:
        torch.testing.assert_close(replay[key], data[:, 2:][key], rtol=1e-4, atol=1e-5)


class _PerceptionEnv(EnvBase):
    """Minimal batched env emitting the perception inputs; world 0 ends every 3 steps."""

    def __init__(self, cfg, num_actions, num_worlds=2):
        super().__init__(batch_size=torch.Size([num_worlds]))
        io = cfg.io
        h = io.image_size
        n = num_worlds
        self.shapes = {
            "depth_goal_stack": (io.num_frames, io.stack_channels, h, h),
            "depth": (1, h, h),
            "goal_gps": (2,),
            "waypoint_gps": (2,),
            "goal_next": (2,),
            "proprio": (io.proprio_dim,),
        }
        self.observation_spec = Composite(
            {k: Unbounded(shape=(n, *s)) for k, s in self.shapes.items()}, shape=(n,)
        )
        self.action_spec = Unbounded(shape=(n, num_actions))
        self.reward_spec = Unbounded(shape=(n, 1))
        self.lengths = torch.tensor([3, 1000])
        self.count = torch.zeros(n, dtype=torch.long)

    def _obs(self):
        n = self.batch_size[0]
        return {k: torch.rand(n, *s) for k, s in self.shapes.items()}

    def _reset(self, td):
        reset = td.get("_reset", None) if td is not None else None
        mask = torch.ones(self.batch_size, dtype=torch.bool) if reset is None else reset.view(-1)
        self.count[mask] = 0
        done = torch.zeros(*self.batch_size, 1, dtype=torch.bool)
        return TensorDict({**self._obs(), "done": done, "terminated": done.clone()},
                          batch_size=self.batch_size)

    def _step(self, td):
        self.count += 1
        done = (self.count >= self.lengths).unsqueeze(-1)
        return TensorDict(
            {**self._obs(), "reward": torch.zeros(*self.batch_size, 1), "done": done,
             "terminated": done.clone()},
            batch_size=self.batch_size,
        )

    def _set_seed(self, seed):
        torch.manual_seed(seed)


@pytest.mark.parametrize("name", ["tcvit", "tcvit_ct"])
def test_collector_and_training_replay(cfg, name):
    """Primers + InitTracker + Collector; replaying the batch in recurrent mode agrees."""
    torch.manual_seed(0)
    perception = make_perception(name, cfg)
    actor = make_locomotion_actor(LocomotionConfig(proprio_dim=PROPRIO, num_actions=10))
    policy = TensorDictSequential(perception, actor)
    env = TransformedEnv(_PerceptionEnv(cfg, 10), InitTracker())
    env.append_transform(get_primers_from_module(policy))
    collector = Collector(env, policy, frames_per_batch=16, total_frames=16)
    data = next(iter(collector))
    collector.shutdown()
    assert data.batch_size == (2, 8)
    assert data["action"].shape == (2, 8, 10)
    assert data["z_uni"].shape == (2, 8, 32)
    assert data["is_init"][0].sum() >= 2  # world 0 restarted inside the batch
    for key in STATE_KEYS[name]:
        assert key in data.keys()
    replay = data.exclude(*OUTS, "perception_features", "perception_memory_in",
                          "perception_memory_out")
    replay = corrupt_later_states(replay, name)
    with torch.no_grad(), set_recurrent_mode(True):
        replay = perception(replay)
    for key in OUTS:
        torch.testing.assert_close(replay[key], data[key], rtol=1e-4, atol=1e-5)
