"""TC-ViT + locomotion policy acting in the real env with the transforms (issues 5-6)."""

import pytest
import torch
from scenes import BoxScene
from torchrl.envs import check_env_specs

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training.student import make_student, student_env


@pytest.mark.parametrize("perception", ["tcvit", "vanilla", "rmab"])
def test_student_policy_rollout_in_hiking_env(perception):
    torch.manual_seed(0)
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=2, mode="student", num_threads=1), trails=BoxScene())
    student = make_student(env, perception)
    tenv = student_env(env, student)
    check_env_specs(tenv, seed=0)
    calls = []
    student.perception.register_forward_hook(lambda mod, args, out: calls.append(1))
    with torch.no_grad():
        td = tenv.rollout(12, student.policy, break_when_any_done=False)
    actions = td["action"]
    assert actions.shape == (2, 12, env.A)
    assert env.action_spec.is_in(actions[:, 0].clamp(-5, 5))
    assert torch.isfinite(actions).all()
    assert td["goal_next"].shape == (2, 12, 2)
    # one perception forward per tick: the reset step, then every 5th step (steps 0, 5, 10)
    assert len(calls) == 3
