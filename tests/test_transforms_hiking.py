"""The transforms on the real HikingEnv (issue 5)."""

import torch
from scenes import BoxScene
from torchrl.envs import Compose, TransformedEnv, check_env_specs

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.transforms import DepthHistory, GoalTiling


def test_check_env_specs_with_depth_history_and_goal_tiling():
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=2, mode="student", num_threads=1), trails=BoxScene())
    tenv = TransformedEnv(env, Compose(DepthHistory(), GoalTiling()))
    check_env_specs(tenv, seed=0)
    td = tenv.rollout(12)
    stack = td["next", "depth_goal_stack"]
    assert stack.shape == (2, 12, 4, 2, 64, 64)
    # the newest frame of the stack is the env's current depth frame
    assert torch.equal(stack[:, :, -1, 0], td["next", "depth"][:, :, 0])
    # frames enter only on perception ticks (every 5th step): the stack changes only there
    changed = (td["next", "depth_stack"][:, 1:] != td["next", "depth_stack"][:, :-1]).flatten(2).any(-1)
    ticks = td["next", "perception_tick"][:, 1:, 0]
    assert not (changed & ~ticks).any()
