"""``collector.backend=ray`` (legoh_rl/training/ray_collection.py): oracle PPO trained by two Ray
workers of a local Ray cluster on this machine, their env state in the checkpoint, the weights on
the workers after every update, an exact resume; the settings and a missing Ray refused before any
work, with messages that name them."""

import signal
import sys
from pathlib import Path

import pytest
import ray
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from worker_checks import check_mirrored_workers

from legoh_rl.training.checkpoint import CheckpointError, load_checkpoint
from legoh_rl.training.ray_collection import (
    RayOptions,
    RayWorkerCollector,
    _check_room,
    _init_ray,
    ray_options,
)
from legoh_rl.training.runner import _check_slices

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

ENV = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=2", "logger.backend=csv"]
TINY = ENV + ["collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2"]
RAY = TINY + ["collector.workers=2", "collector.backend=ray"]


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


@pytest.fixture(autouse=True)
def no_ray_left():
    """Whatever a test leaves, Ray is down after it."""
    yield
    if ray.is_initialized():
        ray.shutdown()


def test_oracle_trains_on_two_ray_workers_and_resumes(tmp_path, monkeypatch):
    synced = []  # after each weight update: do both workers run the trained policy's weights?
    send = RayWorkerCollector.update_policy_weights_

    def checked_send(self, *args, **kwargs):
        send(self, *args, **kwargs)
        trained = self._trained.state_dict()
        synced.append([all(torch.equal(remote[k], v) for k, v in trained.items())
                       for remote in self.map_fn("policy.state_dict")])

    monkeypatch.setattr(RayWorkerCollector, "update_policy_weights_", checked_send)
    ck = tmp_path / "ck"
    first = oracle_ppo.train(cfg_of("oracle_ppo", RAY + ["collector.total_frames=64", f"checkpoint.dir={ck}"]))
    assert first["iteration"] == 2 and first["frames"] == 64  # two [4, 8] batches of 2 x [2, 8]
    assert synced == [[True, True]] * 3  # before the first batch, then after each update
    assert not ray.is_initialized()  # the run started its own Ray (address=local) and stopped it
    saved = load_checkpoint(ck / "last.pt")
    check_mirrored_workers(saved, 2, 16)  # 2 batches x 8 steps
    assert saved["config"]["collector"]["backend"] == "ray"
    # the same K: the workers get their states back and go on
    synced.clear()
    same = oracle_ppo.train(cfg_of("oracle_ppo", RAY + ["collector.total_frames=96", f"checkpoint.dir={ck}",
                                                        "checkpoint.resume=auto"]))
    assert same["iteration"] == 3 and same["frames"] == 96 and synced == [[True, True]] * 2
    resumed = load_checkpoint(ck / "last.pt")["env"]
    assert resumed["global_steps"] == 24 and len(resumed["workers"]) == 2


def test_without_ray_the_error_names_the_install_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray: ImportError, as where it is not installed
    with pytest.raises(ImportError, match=r"collector.backend=ray needs Ray.*pip install 'legoh-rl\[ray\]'"):
        oracle_ppo.train(cfg_of("oracle_ppo", RAY + [f"checkpoint.dir={tmp_path / 'ck'}"]))
    assert not (tmp_path / "ck").exists()


@pytest.mark.parametrize("override, message", [
    ("collector.backend=rays", r"collector.backend must be one of \['local', 'ray'\], got 'rays'"),
    ("collector.ray.num_cpus_per_worker=0", r"collector.ray.num_cpus_per_worker must be a positive integer, got 0"),
    ("collector.ray.memory_per_worker_gib=-1", r"collector.ray.memory_per_worker_gib must be a positive number"),
    ("collector.ray.memory_per_worker_gib=inf", r"collector.ray.memory_per_worker_gib must be a positive number.*got inf"),
    ("collector.ray.address=''", r"collector.ray.address must be local, auto, <host>:<port> or null, got ''"),
    ("+collector.ray.num_gpus=1", r"collector.ray has no setting 'num_gpus'"),
])
def test_bad_settings_are_refused_before_any_work(tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        oracle_ppo.train(cfg_of("oracle_ppo", RAY + [override, f"checkpoint.dir={tmp_path / 'ck'}"]))
    assert not (tmp_path / "ck").exists()


def test_the_recipe_defaults_are_valid_ray_options():
    for name in ("oracle_ppo", "unified"):
        assert ray_options(cfg_of(name, []).collector.ray) == RayOptions()
    assert RayOptions().remote_config() == {"num_cpus": 1, "num_gpus": 0, "memory": 2 * 2**30}
    assert RayOptions(address="auto").init_config() == {"address": "auto"}


class FakeRay:
    """A Ray cluster of 2 CPUs and 3 GiB for tasks."""

    @staticmethod
    def cluster_resources():
        return {"CPU": 2.0, "memory": 3.0 * 2**30}


def test_a_cluster_too_small_for_the_workers_is_refused():
    _check_room(FakeRay, 2, RayOptions(memory_per_worker_gib=1.5))  # fits exactly
    with pytest.raises(RuntimeError, match=r"has 2 CPUs, collector.workers=2 x collector.ray.num_cpus_per_worker=2 "
                                           r"need 4"):
        _check_room(FakeRay, 2, RayOptions(num_cpus_per_worker=2))
    with pytest.raises(RuntimeError, match=r"3.0 GiB for tasks, collector.workers=2 x "
                                           r"collector.ray.memory_per_worker_gib=2.0 need 4.0"):
        _check_room(FakeRay, 2, RayOptions(memory_per_worker_gib=2.0))


class Resumed:
    """A resumed trainer whose env state came with ``slice_states``."""

    def __init__(self, slice_states):
        self.iteration, self.frames = 3, 96
        self.env = type("Env", (), {"slice_states": slice_states})()


@pytest.mark.parametrize("allow", [False, True])
def test_a_resume_needs_the_same_worker_layout_on_either_backend(allow):
    cfg = OmegaConf.create({"collector": {"allow_new_workers": allow}, "checkpoint": {"dir": "ck"}})
    two = [{"rng": 0}, {"rng": 1}]
    assert _check_slices(cfg, Resumed(two), 2, pooled=True) is False  # local or Ray K=2: exact
    # one Ray worker is not the main process itself: its random stream is not the one-process run's
    if allow:
        assert _check_slices(cfg, Resumed(None), 1, pooled=True) is True
        assert _check_slices(cfg, Resumed([{"rng": 0}]), 1, pooled=False) is False
    else:
        with pytest.raises(CheckpointError, match=r"collected by the main process itself, this run has "
                                                  r"collector.workers=1 \(a Ray worker\)"):
            _check_slices(cfg, Resumed(None), 1, pooled=True)
        with pytest.raises(CheckpointError, match=r"collected by 1 worker process\(es\), this run has collector.workers=1"):
            _check_slices(cfg, Resumed([{"rng": 0}]), 1, pooled=False)


class InitRay:
    """``ray.init`` as far as signals go: it installs a SIGTERM handler of its own (exit at once)."""

    @staticmethod
    def init(**kwargs):
        assert kwargs == {"address": "local", "include_dashboard": False}
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))


def test_starting_ray_leaves_the_runs_sigterm_handler():
    received = []

    def graceful(signum, frame):  # the runner's GracefulStop: checkpoint, then stop
        received.append(signum)

    before = signal.signal(signal.SIGTERM, graceful)
    try:
        _init_ray(InitRay, RayOptions())
        assert signal.getsignal(signal.SIGTERM) is graceful
    finally:
        signal.signal(signal.SIGTERM, before)
