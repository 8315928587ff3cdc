"""Training with ``collector.workers=2`` end to end (oracle PPO and the unified student): batches
from two worker processes, their env state in the checkpoint, exact resume with the same K, a
clear refusal with another K unless ``collector.allow_new_workers``."""

import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from worker_checks import check_mirrored_workers

from legoh_rl.training.checkpoint import CheckpointError, load_checkpoint

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

ENV = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=2", "logger.backend=csv"]
TINY = ENV + ["collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2"]


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def test_oracle_with_two_workers_checkpoints_their_state_and_resumes(tmp_path):
    ck = tmp_path / "ck"
    first = oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.workers=2", "collector.total_frames=64",
                                                          f"checkpoint.dir={ck}"]))
    assert first["iteration"] == 2 and first["frames"] == 64  # two [4, 8] batches of 2 x [2, 8]
    saved = load_checkpoint(ck / "last.pt")
    check_mirrored_workers(saved, 2, 16)  # 2 batches x 8 steps
    assert saved["config"]["device"] == "cpu"  # auto, resolved and recorded
    # another K: refused, naming both counts and the way on
    other = TINY + ["collector.workers=1", "collector.total_frames=96", f"checkpoint.dir={ck}", "checkpoint.resume=auto"]
    with pytest.raises(CheckpointError, match=r"collected by 2 worker.*collector.workers=1"):
        oracle_ppo.train(cfg_of("oracle_ppo", other))
    # the same K: continues where it stopped
    same = oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.workers=2", "collector.total_frames=96",
                                                         f"checkpoint.dir={ck}", "checkpoint.resume=auto"]))
    assert same["iteration"] == 3 and same["frames"] == 96
    assert load_checkpoint(ck / "last.pt")["env"]["global_steps"] == 24
    # another K with allow_new_workers: one process from here, the levels carried over
    carried = load_checkpoint(ck / "last.pt")["env"]["curriculum"]["levels"]
    cfg = cfg_of("oracle_ppo", other[:-3] + ["collector.total_frames=128", f"checkpoint.dir={ck}",
                                              "checkpoint.resume=auto", "collector.allow_new_workers=true"])
    parts = oracle_ppo.build(cfg)
    assert np.array_equal(parts.env.curriculum.levels, carried)
    last = oracle_ppo.train(cfg, env=parts.env)
    assert last["frames"] == 128 and "workers" not in load_checkpoint(ck / "last.pt")["env"]


def test_workers_must_divide_the_worlds_before_any_work(tmp_path):
    with pytest.raises(ValueError, match=r"collector.workers=3 must divide env.num_envs=4"):
        oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.workers=3", f"checkpoint.dir={tmp_path}"]))


def test_unified_student_trains_with_two_workers(tmp_path):
    teacher_dir = tmp_path / "oracle"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={teacher_dir}"]))
    ck = tmp_path / "student"
    out = unified.train(cfg_of("unified", ENV + [
        f"teacher={teacher_dir / 'last.pt'}", "collector.steps_per_env=10", "dagger_iters=1", "hlm.warmup_iters=1",
        "ppo.num_epochs=1", "collector.workers=2", "collector.total_frames=80", f"checkpoint.dir={ck}"]))
    assert out["iteration"] == 2 and out["frames"] == 80
    state = load_checkpoint(ck / "last.pt")
    assert state["meta"]["kind"] == "student" and len(state["env"]["workers"]) == 2
