"""rsl_rl (rsl-rl-lib 5.5) on the hiking env: the VecEnv adapter's observation groups, steps and
autoreset, a few iterations of rsl_rl's OnPolicyRunner, and its ONNX export run by onnxruntime."""

import importlib
import sys

import numpy as np
import onnxruntime as ort
import pytest
import torch
from rsl_rl.env import VecEnv
from rsl_rl.runners import OnPolicyRunner
from scenes import BoxScene

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.rsl_rl_env import OBS_GROUPS, HikingRslRlEnv


def _env(n=6, policy_keys=None, critic_keys=None, **kw):
    kw.setdefault("num_threads", 1)
    return HikingRslRlEnv(HikingEnvConfig(num_envs=n, **kw), trails=BoxScene(), policy_keys=policy_keys,
                          critic_keys=critic_keys)


def test_observation_groups_steps_and_autoreset():
    env = _env(n=4, episode_length_s=0.1)  # 5-step episodes
    assert isinstance(env, VecEnv) and env.num_envs == 4 and env.num_actions == 10
    assert env.max_episode_length == 5 and env.step_dt == pytest.approx(0.02) and env.unwrapped is env
    obs = env.get_observations()
    assert set(obs.keys()) == {"policy", "critic"} and obs.batch_size == (4,)
    # H1 oracle: proprio 37 + scandots 132 + expert goals 3 x 2; the critic adds privileged (8 + 10)
    assert obs["policy"].shape == (4, 175) and obs["critic"].shape == (4, 193)
    td = env.env.reset()
    torch.testing.assert_close(obs["critic"][:, :175], obs["policy"])
    expected_policy = torch.cat([td["proprio"], td["scandots"], td["expert_goals"].flatten(1)], dim=1)
    torch.testing.assert_close(env.get_observations()["policy"][:, :37], expected_policy[:, :37])
    actions = torch.full((4, 10), 0.4)
    for step in range(1, 6):
        obs, rewards, dones, extras = env.step(actions)
        assert rewards.shape == (4,) and rewards.dtype == torch.float32 and dones.dtype == torch.long
        assert env.episode_length_buf.tolist() == [step % 5] * 4  # 0 after the reset at step 5
        if step < 5:
            assert not dones.any() and "log" not in extras and not extras["time_outs"].any()
    # the time limit: truncations (bootstrapped by PPO), the worlds reset within the step
    assert dones.tolist() == [1] * 4 and extras["time_outs"].all()
    prev_action = slice(5 + 20, 5 + 30)
    assert not obs["policy"][:, prev_action].any()  # first observation of a new episode
    assert extras["log"]["Episode/ttf"].tolist() == pytest.approx([0.1] * 4)
    assert set(extras["log"]) >= {"Episode/success", "Episode/trail_completion", "Episode/level"}
    # rsl_rl moves the clocks (learn(init_at_random_ep_len=True)): the env's own clock moves
    env.episode_length_buf = torch.tensor([0, 1, 2, 3])
    _, _, dones, extras = env.step(actions)
    assert env.env.episode_step.tolist() == [1, 2, 3, 4]
    env.episode_length_buf = torch.tensor([4, 0, 0, 0])
    _, _, dones, extras = env.step(actions)
    assert dones.tolist() == [1, 0, 0, 0] and extras["time_outs"].tolist() == [True, False, False, False]
    with pytest.raises(ValueError, match=r"actions must have shape \(4, 10\) \(num_envs, num_actions\), got \(4, 3\)"):
        env.step(torch.zeros(4, 3))
    with pytest.raises(ValueError, match=r"episode_length_buf must have shape \(4,\), got \(2,\)"):
        env.episode_length_buf = torch.zeros(2, dtype=torch.long)


def test_group_keys_are_checked_and_a_built_env_is_taken():
    with pytest.raises(ValueError, match=r"policy key 'depth' is not a flat observation of this env"):
        _env(n=2, policy_keys=("proprio", "depth"))
    with pytest.raises(ValueError, match="critic key 'lidar' is not a flat observation"):
        _env(n=2, critic_keys=("proprio", "lidar"))
    hiking = HikingEnv(HikingEnvConfig(num_envs=2, num_threads=1, mode="student"), trails=BoxScene())
    with pytest.raises(ValueError, match="the given HikingEnv already has its trails"):
        HikingRslRlEnv(hiking, trails=BoxScene())
    env = HikingRslRlEnv(hiking)  # student mode: proprio + GPS; the depth image as its own group
    obs = env.get_observations()
    assert obs["policy"].shape == (2, 37 + 2 + 2) and obs["depth"].shape == (2, 1, 64, 64)
    assert obs["critic"].shape == (2, 41 + 132 + 6 + 18)


def test_missing_rsl_rl_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rsl_rl", None)  # import rsl_rl: ImportError, as where it is not installed
    monkeypatch.setitem(sys.modules, "rsl_rl.env", None)
    monkeypatch.delitem(sys.modules, "legoh_rl.envs.rsl_rl_env")
    with pytest.raises(ImportError, match=r"pip install 'legoh-rl\[rsl_rl\]'"):
        importlib.import_module("legoh_rl.envs.rsl_rl_env")


def test_on_policy_runner_trains_and_exports_onnx(tmp_path):
    torch.manual_seed(0)
    env = _env(n=6, episode_length_s=0.12)  # episodes end inside the rollouts: time-outs and logs
    train_cfg = {
        "num_steps_per_env": 8,
        "save_interval": 100,
        "obs_groups": dict(OBS_GROUPS),
        "algorithm": {"class_name": "PPO", "num_learning_epochs": 2, "num_mini_batches": 2, "learning_rate": 1e-3},
        "actor": {"class_name": "MLPModel", "hidden_dims": [32, 32], "obs_normalization": True,
                  "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 1.0}},
        "critic": {"class_name": "MLPModel", "hidden_dims": [32, 32], "obs_normalization": True},
    }
    runner = OnPolicyRunner(env, train_cfg, log_dir=str(tmp_path), device="cpu")
    before = [p.detach().clone() for p in runner.alg.get_policy().parameters()]
    runner.learn(num_learning_iterations=3)
    assert runner.current_learning_iteration == 2
    after = list(runner.alg.get_policy().parameters())
    assert any(not torch.equal(b, a) for b, a in zip(before, after, strict=True))  # the actor learned
    assert (tmp_path / "model_2.pt").is_file()

    runner.export_policy_to_onnx(str(tmp_path))
    session = ort.InferenceSession(str(tmp_path / "policy.onnx"), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["obs"] and session.get_inputs()[0].shape[-1] == 175
    obs = env.get_observations()
    action = session.run(None, {"obs": obs["policy"][:1].numpy()})[0]
    assert action.shape == (1, 10) and np.isfinite(action).all()
    with torch.inference_mode():
        expected = runner.get_inference_policy()(obs)[:1]
    np.testing.assert_allclose(action, expected.numpy(), rtol=1e-4, atol=1e-5)
    actions = torch.zeros(6, 10)
    actions[0] = torch.from_numpy(action[0])
    nxt, rewards, _, _ = env.step(actions)  # one step of the env on the exported policy's action
    assert torch.isfinite(nxt["policy"]).all() and torch.isfinite(rewards).all()
