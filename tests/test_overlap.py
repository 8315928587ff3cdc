"""``collector.overlap`` (issue 52): the next batch collected in a thread during the update.

Which weights collect which batch (hand-derived schedule, on a trainer whose policy writes its
version into every step), determinism, the oracle's resume, the sampling mode kept per thread,
and the clear refusals."""

import json
import sys
import threading
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict.nn import InteractionType, TensorDictModule, set_interaction_type
from tensordict.nn.probabilistic import interaction_type

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training import runner
from legoh_rl.training.checkpoint import load_checkpoint
from legoh_rl.training.prefetch import Prefetch, thread_local_sampling_mode

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2", "logger.backend=csv"]
OVERLAP = ["collector.overlap=true", "update_threads=1"]


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


class _Versioned(torch.nn.Module):
    """Zero actions, and the version of the weights that acted at every step."""

    def __init__(self, actions: int) -> None:
        super().__init__()
        self.actions = actions
        self.register_buffer("version", torch.zeros(()))

    def forward(self, obs):
        zeros = torch.zeros(*obs.shape[:-1], self.actions)
        return zeros, self.version.expand(obs.shape[:-1]).clone()


class _VersionTrainer(runner.Trainer):
    """Each update bumps the behaviour's version and records the versions its batch was collected with."""

    overlap_ready = True
    collector_kwargs = {"auto_register_policy_transforms": False}

    def __init__(self, env: HikingEnv) -> None:
        self.env = self.collect_env = env
        key = "proprio" if "proprio" in env.observation_spec.keys() else next(iter(env.observation_spec.keys()))
        self.behaviour = TensorDictModule(_Versioned(env.action_spec.shape[-1]), in_keys=[key],
                                          out_keys=["action", "version"])
        self.seen: list[float] = []

    def update(self, data) -> dict[str, float]:
        versions = data["version"].unique()
        assert versions.numel() == 1, versions  # one set of weights per batch
        self.seen.append(float(versions))
        self.behaviour.module.version += 1
        return {"reward/total": 0.0, "curriculum/mean_level": 0.0}

    def state_dict(self) -> dict:
        return {"version": float(self.behaviour.module.version)}


def _versions(tmp_path, extra):
    cfg = cfg_of("oracle_ppo", TINY + ["collector.total_frames=224", f"checkpoint.dir={tmp_path / 'ck'}",
                                       "checkpoint.every=3", "update_threads=1", *extra])
    built = {}

    def build(c):
        env = HikingEnv(HikingEnvConfig(num_envs=4, categories=("randommix",), variants=1, num_threads=1, seed=3))
        built["t"] = _VersionTrainer(env)
        return built["t"]

    runner.train(cfg, lambda c: None, build)
    rows = [json.loads(line) for line in (tmp_path / "ck" / "metrics.jsonl").read_text().splitlines()]
    return built["t"].seen, rows


def test_each_batch_is_collected_by_the_weights_before_the_update_it_overlaps(tmp_path):
    # 7 batches, a checkpoint every 3 iterations. Update k makes version k + 1. Overlapped, batch
    # k + 1 is collected during update k by version k, except when iteration k + 1 ends with a
    # checkpoint (k + 1 = 3, 6): then it is collected after it, by version k + 1.
    seen, rows = _versions(tmp_path / "a", OVERLAP[:1])
    assert seen == [0, 0, 1, 3, 3, 4, 6]
    assert [r["train/overlapped"] for r in rows] == [1, 1, 0, 1, 1, 0, 1]
    assert all(r["train/wait_s"] >= 0 for r in rows if r["train/overlapped"])
    assert all(r["train/iteration_s"] > 0 and r["train/collect_s"] > 0 for r in rows)
    seq, rows = _versions(tmp_path / "b", [])  # in turn: batch k by version k
    assert seq == [0, 1, 2, 3, 4, 5, 6] and all("train/overlapped" not in r for r in rows)


def _oracle(tmp_path, frames, *extra):
    return oracle_ppo.train(cfg_of("oracle_ppo", TINY + OVERLAP + [f"collector.total_frames={frames}",
                                                                  f"checkpoint.dir={tmp_path}", *extra]))


def test_overlapped_oracle_is_deterministic_and_resumes_its_minibatch_stream(tmp_path):
    # the clock's feedforward annealed from 1 at 32 frames to 0 at 96: each batch is logged with
    # the gain it was collected with, though the next batch's is set before the update
    gait = ["env.gait_period=0.8", "env.gait_feedforward=1.0", "feedforward_anneal=[32,96]"]
    for run in ("a", "b"):
        out = _oracle(tmp_path / run, 160, "checkpoint.every=3", *gait)
        assert out["iteration"] == 5 and out["frames"] == 160
    a, b = (load_checkpoint(tmp_path / run / "last.pt") for run in ("a", "b"))
    for k, v in a["loss"].items():  # thread timing does not enter the numbers
        assert torch.equal(v, b["loss"][k]), k
    assert torch.equal(a["minibatch_rng"], b["minibatch_rng"])
    gains = [json.loads(line)["train/gait_feedforward"] for line in (tmp_path / "a" / "metrics.jsonl").open()]
    assert gains == pytest.approx([1.0, 1.0, 0.5, 0.0, 0.0])
    parts = oracle_ppo.build(cfg_of("oracle_ppo", TINY + OVERLAP + gait + ["collector.total_frames=224",
                                                                    f"checkpoint.dir={tmp_path / 'a'}",
                                                                    "checkpoint.resume=auto"]))
    assert parts.frames == 160 and torch.equal(parts.generator.get_state(), a["minibatch_rng"])
    out = _oracle(tmp_path / "a", 224, "checkpoint.resume=auto", *gait)
    assert out["iteration"] == 7 and load_checkpoint(tmp_path / "a" / "last.pt")["frames"] == 224


def test_the_sampling_mode_is_each_threads_own():
    thread_local_sampling_mode()
    thread_local_sampling_mode()  # idempotent
    seen = {}
    entered, leave = threading.Event(), threading.Event()

    def other():
        with set_interaction_type(InteractionType.RANDOM):
            entered.set()
            leave.wait(5)
            seen["other"] = interaction_type()

    thread = threading.Thread(target=other)
    thread.start()
    entered.wait(5)
    with set_interaction_type(InteractionType.DETERMINISTIC):  # what a loss does in the update's thread
        seen["main"] = interaction_type()
        leave.set()
        thread.join(5)
    assert seen == {"main": InteractionType.DETERMINISTIC, "other": InteractionType.RANDOM}


def test_prefetch_raises_the_collections_error_in_the_caller():
    def broken():
        raise RuntimeError("the env diverged past repair")
        yield

    with pytest.raises(RuntimeError, match="diverged past repair"):
        Prefetch(broken()).result()
    assert Prefetch(iter([])).result()[0] is None  # a finished collector: no batch


@pytest.mark.parametrize(("extra", "match"), [
    (["collector.workers=2"], r"collector.workers=1 and collector.backend=local \(got workers=2"),
    (["update_threads=2"], r"update_threads=1 or null, got torch_threads=1, update_threads=2"),
    (["torch_threads=2", "update_threads=1"], r"got torch_threads=2"),
])
def test_overlap_refuses_what_it_cannot_do_before_any_work(tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.overlap=true", f"checkpoint.dir={tmp_path}", *extra]))
    assert not (tmp_path / "last.pt").exists()


def test_overlap_is_for_the_cpu(tmp_path):
    cfg = cfg_of("oracle_ppo", TINY + OVERLAP + [f"checkpoint.dir={tmp_path}", "device=cuda:1"])
    with pytest.raises(ValueError, match=r"on the CPU \(device=cpu\), got device=cuda:1"):
        runner.collector_overlap(cfg)  # (the recipes' own check refuses a GPU this machine lacks first)


def test_a_trainer_that_does_not_allow_overlap_is_named(tmp_path):
    cfg = cfg_of("oracle_ppo", TINY + OVERLAP + [f"checkpoint.dir={tmp_path}"])

    class Plain(_VersionTrainer):
        overlap_ready = False

    env = HikingEnv(HikingEnvConfig(num_envs=4, categories=("randommix",), variants=1, num_threads=1))
    with pytest.raises(ValueError, match=r"\(Plain\) does not allow collecting during its update"):
        runner.train(cfg, lambda c: None, lambda c: Plain(env))


@pytest.fixture(scope="module")
def teacher(tmp_path_factory):
    ck = tmp_path_factory.mktemp("oracle")
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}"]))
    return ck / "last.pt"


def _student(teacher, ck, frames, *extra):
    """experiment=student_h1's cheap update on a tiny env: DAgger (decaying beta) with the replay
    window and the encoder on a fraction of the ticks, then PPO + HLM."""
    return unified.train(cfg_of("unified", TINY[:4] + ["logger.backend=csv", f"teacher={teacher}",
                                                       "collector.steps_per_env=10", "dagger_iters=3",
                                                       "hlm.warmup_iters=3", "dagger_minibatches=2",
                                                       "minibatch_split=strided", "encoder_grad_fraction=0.5",
                                                       "dagger_replay.capacity=40", "dagger_replay.batch_size=8",
                                                       "dagger_replay.steps=2", "collector.overlap=true",
                                                       "torch_threads=1", f"collector.total_frames={frames}",
                                                       f"checkpoint.dir={ck}",
                                                       *extra]))


@pytest.mark.parametrize("threads", [1, 2])
def test_overlapped_student_is_deterministic_logs_its_betas_and_resumes(teacher, tmp_path, threads):
    """Also with the physics and the depth render on 2 threads: torch's thread count is each
    thread's own, so the render's in the collecting thread does not reach the update."""
    extra = [f"env.num_threads={threads}"]
    for run in ("a", "b"):
        out = _student(teacher, tmp_path / run, 200, "checkpoint.every=3", *extra)
        assert out["iteration"] == 5
    a, b = (load_checkpoint(tmp_path / run / "last.pt") for run in ("a", "b"))
    for part in ("perception", "actor", "critic", "vae"):
        for k, v in a[part].items():
            assert torch.equal(v, b[part][k]), (part, k)
    assert torch.equal(a["minibatch_rng"], b["minibatch_rng"])
    rows = [json.loads(line) for line in (tmp_path / "a" / "metrics.jsonl").open()]
    cfg = cfg_of("unified", [f"teacher={teacher}", "dagger_iters=3"])
    assert [r["train/dagger_beta"] for r in rows] == [unified.beta_at(i, cfg) for i in range(5)]
    assert [r["train/overlapped"] for r in rows] == [1, 1, 0, 1, 1]
    out = _student(teacher, tmp_path / "a", 240, "checkpoint.resume=auto", *extra)
    assert out["iteration"] == 6


def test_a_thread_count_set_in_one_thread_stays_there():
    """What the student's overlap rests on: the depth render's torch_threads(n) in the collecting
    thread leaves the updating thread's count (ATen's, OpenMP's, MKL's) as it was."""
    torch.set_num_threads(1)
    seen = {}

    def other():
        torch.set_num_threads(2)
        seen["other"] = torch.get_num_threads()

    thread = threading.Thread(target=other)
    thread.start()
    thread.join()
    assert seen["other"] == 2 and torch.get_num_threads() == 1
    assert "mkl_get_max_threads() : 1" in torch.__config__.parallel_info() or not torch.backends.mkl.is_available()


def test_a_one_process_collector_on_the_trainers_own_weights_needs_no_push():
    """The in-turn loop pushes the trained weights to the collector only when it runs a copy: a
    one-process Collector on the behaviour itself sees every update in place (the in-turn schedule
    above: batch k by version k), a copy of it does not."""
    from torchrl.collectors import Collector

    env = HikingEnv(HikingEnvConfig(num_envs=2, categories=("randommix",), variants=1, num_threads=1, seed=3))
    t = _VersionTrainer(env)
    kwargs = dict(frames_per_batch=4, total_frames=8, **t.collector_kwargs)
    own = Collector(env, t.behaviour, **kwargs)
    copy = Collector(env, __import__("copy").deepcopy(t.behaviour), **kwargs)
    try:
        assert runner.weights_shared(own, t.behaviour)
        assert not runner.weights_shared(copy, t.behaviour)
        assert not runner.weights_shared(object(), t.behaviour)
        t.behaviour.module.version += 5  # an update in place reaches the shared collector's next batch
        assert next(iter(own))["version"].unique().tolist() == [5.0]
        assert next(iter(copy))["version"].unique().tolist() == [0.0]
    finally:
        own.shutdown()
        copy.shutdown()
