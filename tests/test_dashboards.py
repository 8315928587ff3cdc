"""What a training run shows on its dashboard: the wandb config keeps the env section, one log
call per iteration, and the panels users of rsl_rl / mjlab expect (episode return and length,
how episodes end, explained variance, collection vs update time, the level distribution)."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict

from legoh_rl.training.logging import runtime_versions
from legoh_rl.training.stats import curriculum_stats, ending_stats, explained_variance, return_stats

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

# 4 worlds, 8 steps per iteration, 0.1 s episodes (5 control steps): episodes end in every batch
TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "env.episode_length_s=0.1", "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2"]


def cfg_of(overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name="oracle_ppo", overrides=overrides)


def _ends(done, terminated, success, reward=None, steps=None):
    n = len(done)
    col = lambda v, dt: torch.tensor(v, dtype=dt).reshape(1, n, 1)  # noqa: E731  [1 world, n steps, 1]
    nxt = {"done": col(done, torch.bool), "terminated": col(terminated, torch.bool),
           "episode": {"success": col(success, torch.float32)}}
    if reward is not None:
        nxt["episode_reward"] = col(reward, torch.float32)
    if steps is not None:
        nxt["step_count"] = col(steps, torch.int64)
    return TensorDict({"next": nxt}, batch_size=[1, n])


def test_ending_and_return_stats_hand_made_batch():
    # four ends: goal (terminated, success), fall (terminated, no success), two timeouts; one
    # step not done (ignored whatever it holds)
    data = _ends(done=[1, 1, 1, 0, 1], terminated=[1, 1, 0, 1, 0], success=[100, 0, 0, 100, 0],
                 reward=[10.0, 2.0, 4.0, 99.0, 0.0], steps=[50, 10, 100, 7, 100])
    assert ending_stats(data) == {"episode/end_goal": 25.0, "episode/end_fall": 25.0, "episode/end_timeout": 50.0}
    assert return_stats(data) == {"episode/return": 4.0, "episode/length": 65.0}
    none = _ends(done=[0, 0], terminated=[0, 0], success=[0, 0])
    assert ending_stats(none) == {} and return_stats(none) == {}
    no_counters = _ends(done=[1], terminated=[1], success=[0])
    assert return_stats(no_counters) == {}


def test_explained_variance_hand_computed():
    targets = torch.tensor([1.0, 2.0, 3.0, 4.0])
    assert explained_variance(targets, targets) == 1.0
    assert explained_variance(torch.full((4,), 2.5), targets) == pytest.approx(0.0)
    # residual [0.5, -0.5, 0.5, -0.5]: var 1/3 (unbiased) against var(targets) 5/3
    values = targets + torch.tensor([-0.5, 0.5, -0.5, 0.5])
    assert explained_variance(values, targets) == pytest.approx(1.0 - (1 / 3) / (5 / 3))
    assert math.isnan(explained_variance(targets, torch.ones(4)))


def test_curriculum_level_shares():
    out = curriculum_stats(np.array([0, 0, 1, 4]), np.array([0, 0, 0, 0]), ("randommix",))
    assert [out[f"curriculum/share_level{k}"] for k in range(5)] == [0.5, 0.25, 0.0, 0.0, 0.25]


def test_training_logs_the_new_panels(tmp_path):
    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of(TINY + ["logger.backend=csv", "collector.total_frames=64", f"checkpoint.dir={ck}"]))
    rows = [json.loads(line) for line in (ck / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2
    for row in rows:
        assert row["episode/length"] >= 1 and math.isfinite(row["episode/return"])
        ends = row["episode/end_goal"] + row["episode/end_fall"] + row["episode/end_timeout"]
        assert ends == pytest.approx(100.0)
        assert row["train/collect_s"] > 0 and row["train/update_s"] > 0
        assert row["train/explained_variance"] is None or row["train/explained_variance"] <= 1.0
        assert sum(row[f"curriculum/share_level{k}"] for k in range(5)) == pytest.approx(1.0)
    # a 0.1 s episode is 5 control steps: no ended episode is longer
    assert max(row["episode/length"] for row in rows) <= 5


def test_wandb_run_keeps_the_env_config_and_logs_once_per_iteration(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb")
    calls, configs = [], []
    real_log = wandb.sdk.wandb_run.Run.log

    def counting_log(self, data, *args, **kwargs):
        calls.append(sorted(data))
        configs.append(dict(self.config))  # what the run records (and `wandb sync` uploads)
        return real_log(self, data, *args, **kwargs)

    monkeypatch.setattr(wandb.sdk.wandb_run.Run, "log", counting_log)
    monkeypatch.setenv("WANDB_MODE", "offline")
    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of(TINY + ["logger.backend=wandb", "collector.total_frames=96", f"checkpoint.dir={ck}"]))
    assert len(calls) == 3  # three iterations, one call each, every figure in it
    assert "reward/total" in calls[0] and "episode/return" in calls[0] and "train/kl" in calls[0]
    saved = configs[-1]
    assert saved["env"]["num_envs"] == 4 and saved["env"]["robot"] == "h1" and saved["env"]["episode_length_s"] == 0.1
    assert saved["runtime"]["torch"] == runtime_versions()["torch"]
