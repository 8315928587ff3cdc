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
    # 8 env steps per world per iteration; the action delay waits for 24 x 8000 of them
    assert [row["env/global_steps"] for row in rows] == [8, 16]
    assert [row["env/action_delay_steps"] for row in rows] == [0, 0]


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


def test_eval_figures_are_numbers():
    from legoh_rl.training.evaluation import eval_scalars, long_table

    rows = {"gap": {"success": (50.0, 5.0)}, "level 1": {"success": (25.0, 0.0)}, "overall": {"success": (40.0, 2.0)}}
    assert eval_scalars(rows) == {"eval/gap/success": 50.0, "eval/gap/success_std": 5.0,
                                  "eval/level_1/success": 25.0, "eval/level_1/success_std": 0.0,
                                  "eval/overall/success": 40.0, "eval/overall/success_std": 2.0}
    columns, data = long_table(rows, "category")
    assert columns == ["by", "group", "metric", "mean", "std"]
    assert data[0] == ["category", "gap", "success", 50.0, 5.0] and all(isinstance(r[3], float) for r in data)


def test_evaluation_logs_numeric_columns_in_the_experiments_group(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb")
    from legoh_rl.training import eval_run

    assert eval_run.checkpoint_experiment(str(RECIPES.parent / "checkpoints" / "oracle_h1.pt")) == \
        "oracle_h1_long_stride"
    assert eval_run.checkpoint_experiment("zero") is None
    logged, inits = [], []
    real_log, real_init = wandb.sdk.wandb_run.Run.log, wandb.init

    def log(self, data, *args, **kwargs):
        logged.append(dict(data))
        return real_log(self, data, *args, **kwargs)

    def init(*args, **kwargs):
        inits.append(kwargs)
        return real_init(*args, **kwargs)

    monkeypatch.setattr(wandb.sdk.wandb_run.Run, "log", log)
    monkeypatch.setattr(wandb, "init", init)
    monkeypatch.setenv("WANDB_MODE", "offline")
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        cfg = compose(config_name="evaluate", overrides=[
            "checkpoint=zero", "categories=[randommix,gap]", "levels=[0]", "robots_per_cell=1", "variants=1",
            "num_threads=1", f"output_dir={tmp_path}", "video=false", "logger.group=my_experiment"])
    out = eval_run.evaluate(cfg)
    assert inits[-1]["group"] == "my_experiment"
    scalars = next(d for d in logged if "eval/overall/success" in d)
    assert scalars["eval/overall/success"] == out["rows"]["overall"]["success"][0] == 0.0
    assert scalars["eval/gap/ttf"] == pytest.approx(out["rows"]["gap"]["ttf"][0]) and "eval/level_0/ttf_std" in scalars
    table = next(d["eval/table"] for d in logged if "eval/table" in d)
    assert table.columns == ["by", "group", "metric", "mean", "std"]
    assert {r[1] for r in table.data} == {"randommix", "gap", "overall", "level 0"}


def test_training_videos_every_k_iterations(tmp_path):
    """logger.video_every=2: a video of the checkpoint's policy after iterations 2 and 4, one
    robot per category (two categories: one row of two tiles)."""
    import imageio.v2 as imageio

    ck = tmp_path / "ck"
    cfg = cfg_of(TINY + ["logger.backend=csv", "collector.total_frames=128", f"checkpoint.dir={ck}",
                         "checkpoint.every=3", "env.categories=[randommix,gap]", "logger.video_every=2",
                         "logger.video_seconds=0.2"])
    oracle_ppo.train(cfg)
    videos = sorted((ck / "videos").glob("*.mp4")) if (ck / "videos").is_dir() else []
    if not videos:
        pytest.skip("no OpenGL context on this machine (the run went on without videos)")
    assert [v.name for v in videos] == ["iteration000002.mp4", "iteration000004.mp4"]
    frames = imageio.mimread(videos[0])
    assert len(frames) == 5 and frames[0].shape == (240, 640, 3)  # 0.2 s at 25 fps; two 320 x 240 tiles
    assert frames[0].std() > 5  # not a blank frame


def test_trajectory_plot_titles_do_not_overlap():
    """Four stacked panels (one per tile): no panel's title runs into the panel above it (its axes
    or its x tick labels) or into another title."""
    from types import SimpleNamespace

    import matplotlib.pyplot as plt
    from scenes import BoxScene

    from legoh_rl.training.evaluation import EvalResult, trajectory_figure

    scene = BoxScene(boxes=[((3.0, 0.0, 0.1), (0.2, 1.0, 0.1))], num_levels=4)
    xs = np.linspace(0.0, 4.0, 50)
    result = EvalResult(trajectories={w: np.stack([xs, 0.1 * w + 0 * xs], 1) for w in range(4)},
                        times={w: xs / 2.0 for w in range(4)}, tiles={w: w for w in range(4)})
    fig = trajectory_figure(SimpleNamespace(trails=scene), result)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        axes = [ax for ax in fig.axes if ax.get_title()]
        assert [ax.get_title() for ax in axes] == [f"flat, level {k}" for k in range(4)]
        titles = [ax.title.get_window_extent(renderer) for ax in axes]
        for k in range(1, len(axes)):
            above = axes[k - 1]
            for box in (above.get_window_extent(renderer), above.xaxis.get_tightbbox(renderer)):
                assert not titles[k].overlaps(box), (k, titles[k], box)
        for i in range(len(titles)):
            for j in range(i + 1, len(titles)):
                assert not titles[i].overlaps(titles[j])
    finally:
        plt.close(fig)
