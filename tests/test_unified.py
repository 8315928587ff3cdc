"""The unified (student) recipe on tiny configs (issue 8): DAgger -> PPO + HLM, ablations, resume."""

import json
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from legoh_rl.training.checkpoint import export_policy, file_digest, load_checkpoint

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

ENV = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1", "logger.backend=csv"]


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


@pytest.fixture(scope="module")
def teacher(tmp_path_factory):
    ck = tmp_path_factory.mktemp("oracle")
    oracle_ppo.train(cfg_of("oracle_ppo", ENV + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={ck}"]))
    return ck / "last.pt"


def tiny(teacher, ck, *extra):
    return cfg_of("unified", ENV + [f"teacher={teacher}", "collector.steps_per_env=10", "dagger_iters=1",
                                    "hlm.warmup_iters=1", "ppo.num_epochs=1", f"checkpoint.dir={ck}", *extra])


def test_student_step_trains_tcvit_with_ppo_imitation_and_hlm(teacher, tmp_path):
    p = unified.build(tiny(teacher, tmp_path))
    before = [q.detach().clone() for q in p.student.perception.parameters()]
    vae_before = [q.detach().clone() for q in p.vae.parameters()]
    with torch.no_grad():  # as in a Collector
        collector_data = p.collect_env.rollout(10, p.student.policy, break_when_any_done=False)
    stats = unified.update(p, collector_data, iteration=1, cfg=tiny(teacher, tmp_path))
    assert stats["train/phase_rl"] == 1.0 and stats["train/hlm_on"] == 1.0
    for key in ("loss/im_latent", "loss/im_action", "loss/hlm_ts", "loss/objective", "loss/critic"):
        assert key in stats and torch.isfinite(torch.tensor(stats[key])), key
    # gradients reached TC-ViT through PPO, L_im and L_hie
    changed = [not torch.equal(a, b) for a, b in zip(before, p.student.perception.parameters(), strict=True)]
    assert sum(changed) > 0.9 * len(changed)
    # the VAE learns only from its own loss (L_rec on teacher actions)
    assert any(not torch.equal(a, b) for a, b in zip(vae_before, p.vae.parameters(), strict=True))


@pytest.mark.parametrize("extra", [[], ["hlm.enabled=false"], ["hlm.vanilla_vae=true", "student.perception=vanilla"]])
def test_unified_runs_end_to_end_and_resumes(teacher, tmp_path, extra):
    out = unified.train(tiny(teacher, tmp_path, "collector.total_frames=80", *extra))
    assert out["iteration"] == 2
    state = load_checkpoint(tmp_path / "last.pt")
    assert state["meta"]["kind"] == "student" and state["iteration"] == 2
    resumed = unified.build(tiny(teacher, tmp_path, "collector.total_frames=120", "checkpoint.resume=auto", *extra))
    assert resumed.iteration == 2 and resumed.frames == 80
    for k, v in state["perception"].items():
        assert torch.equal(resumed.student.perception.state_dict()[k], v)


def test_evaluate_a_student_checkpoint(teacher, tmp_path):
    unified.train(tiny(teacher, tmp_path / "ck", "collector.total_frames=40"))
    cfg = cfg_of("evaluate", [f"checkpoint={tmp_path / 'ck' / 'last.pt'}", "categories=[randommix]", "levels=[0]",
                              "robots_per_cell=2", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}",
                              "video=false", "logger.backend=csv"])
    out = eval_run.evaluate(cfg)
    assert len(out["episodes"]) == 2 and Path(out["table"]).is_file()


def test_bad_teacher_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="teacher: no checkpoint at /nope.pt"):
        unified.build(tiny("/nope.pt", tmp_path))
    with pytest.raises(ValueError, match="unknown student.perception 'resnet'"):
        unified.build(tiny("/nope.pt", tmp_path, "student.perception=resnet"))


def test_dagger_beta_schedule():
    from legoh_rl.training.distill import dagger_beta

    assert [dagger_beta(i, 1.0, 4) for i in range(6)] == [1.0, 0.75, 0.5, 0.25, 0.0, 0.0]
    assert dagger_beta(1, 0.5, 2) == 0.25 and dagger_beta(0, 0.8, 0) == 0.0
    with pytest.raises(ValueError, match=r"beta0 must be in \[0, 1\], got 1.5"):
        dagger_beta(0, 1.5, 10)


def test_dagger_mixture_executes_the_teachers_action_with_probability_beta(teacher, tmp_path):
    from legoh_rl.training.distill import DAggerMixture

    p = unified.build(tiny(teacher, tmp_path))
    mix = DAggerMixture(p.student.policy, p.teacher, seed=0)
    td = p.collect_env.reset()
    expected = p.teacher.label(td.clone())["action_tea"]
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # as the Collector samples
        mix.beta = 1.0
        out = mix(td.clone())
        assert out["teacher_acted"].all() and torch.allclose(out["action"], expected)
        mix.beta = 0.0
        out = mix(td.clone())
        assert not out["teacher_acted"].any() and not torch.allclose(out["action"], expected)
        # the student's action is what the student policy alone writes (same sampling seed)
        torch.manual_seed(3)
        alone = p.student.policy(td.clone())["action"]
        torch.manual_seed(3)
        assert torch.equal(mix(td.clone())["action"], alone)
        # in the imitation phase the student executes its mean action, not a sample
        mix.student_mean = True
        out = mix(td.clone())
        assert torch.equal(out["action"], out["loc"]) and not torch.equal(out["action"], alone)
    # a collection run in the DAgger phase records the mixture and its beta
    out = unified.train(tiny(teacher, tmp_path / "run", "collector.total_frames=80", "dagger_iters=4"))
    assert out["iteration"] == 2 and out["train/dagger_beta"] == pytest.approx(0.75)  # of the 2nd batch
    assert 0.0 < out["train/teacher_acted"] < 1.0  # 40 coin flips at 0.75


def test_dagger_epochs_must_be_positive(teacher, tmp_path):
    with pytest.raises(ValueError, match="^dagger_epochs must be a positive integer, got 0$"):
        unified.build(tiny(teacher, tmp_path, "dagger_epochs=0"))


def test_student_starts_from_the_teachers_action_std(teacher, tmp_path):
    t = unified.Teacher(str(teacher), "h1")
    head = t.networks.actor.head
    assert torch.allclose(t.action_std, head.log_std.exp())  # no ceiling on this teacher
    p = unified.build(tiny(teacher, tmp_path))
    student_std = p.student.actor.module[0].module.head.log_std.exp()
    assert torch.allclose(student_std, torch.full_like(student_std, float(t.action_std.mean())))
    p = unified.build(tiny(teacher, tmp_path, "student.init_std=0.3"))
    assert torch.allclose(p.student.actor.module[0].module.head.log_std.exp(), torch.tensor(0.3))


def test_short_beta_decay_leaves_a_pure_dagger_stretch(teacher, tmp_path):
    cfg = tiny(teacher, tmp_path / "run", "collector.total_frames=80", "dagger_iters=4", "dagger_decay_iters=1")
    assert [unified.beta_at(i, cfg) for i in range(5)] == [1.0, 0.0, 0.0, 0.0, 0.0]
    assert [unified.beta_at(i, tiny(teacher, tmp_path, "dagger_iters=4")) for i in range(3)] == [1.0, 0.75, 0.5]
    out = unified.train(cfg)
    # the 2nd batch: the student acted alone (beta 0) and PPO had not joined yet
    assert out["train/dagger_beta"] == 0.0 and out["train/teacher_acted"] == 0.0 and out["train/phase_rl"] == 0.0
    with pytest.raises(ValueError, match=r"dagger_decay_iters must lie in \(0, dagger_iters=4\], got 5"):
        unified.build(tiny(teacher, tmp_path, "dagger_iters=4", "dagger_decay_iters=5"))


def test_ppo_join_std_sets_the_action_std_the_ppo_phase_starts_from(teacher, tmp_path):
    """student.ppo_join_std: the DAgger phase's last update leaves the actor's std at the given
    value (the first PPO batch samples with it); a run that starts where PPO joins (dagger_iters
    0) starts from it; without the switch the std is the one training left."""
    def stds(path):
        actor = load_checkpoint(path)["actor"]
        return torch.cat([v.exp() for k, v in actor.items() if k.endswith("log_std")])

    cfg = tiny(teacher, tmp_path / "run", "collector.total_frames=120", "dagger_iters=2", "hlm.warmup_iters=2",
               "student.ppo_join_std=0.3", "checkpoint.snapshot_every=1")
    out = unified.train(cfg)
    assert out["iteration"] == 3 and out["train/phase_rl"] == 1.0
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r.get("train/ppo_join_std") for r in rows] == [None, 0.3, None]  # set once, at update 1
    snaps = tmp_path / "run" / "snapshots"
    assert torch.allclose(stds(snaps / "frames000000080.pt"), torch.tensor(0.3))  # before the first PPO batch
    assert not torch.allclose(stds(snaps / "frames000000040.pt"), torch.tensor(0.3))
    assert not torch.allclose(stds(snaps / "frames000000120.pt"), torch.tensor(0.3))  # PPO trains it on
    plain = unified.train(tiny(teacher, tmp_path / "plain", "collector.total_frames=80", "dagger_iters=2",
                               "hlm.warmup_iters=2", "checkpoint.snapshot_every=1"))
    assert "train/ppo_join_std" not in plain
    assert not torch.allclose(stds(tmp_path / "plain" / "snapshots" / "frames000000080.pt"), torch.tensor(0.3))
    p = unified.build(tiny(teacher, tmp_path / "join", "dagger_iters=0", "hlm.warmup_iters=0",
                           "student.ppo_join_std=0.25"))
    heads = [v for k, v in p.student.actor.state_dict().items() if k.endswith("log_std")]
    assert heads and all(torch.allclose(v.exp(), torch.tensor(0.25)) for v in heads)
    with pytest.raises(ValueError, match=r"student.ppo_join_std must be a positive number, got 0 \(or null\)"):
        unified.build(tiny(teacher, tmp_path / "bad", "student.ppo_join_std=0"))


def test_student_of_a_gait_clock_teacher_gets_the_teachers_clock(tmp_path):
    ck = tmp_path / "oracle"
    oracle_ppo.train(cfg_of("oracle_ppo", ENV + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={ck}", "env.gait_period=0.7",
                                                 "env.gait_feedforward=1.0"]))
    p = unified.build(tiny(ck / "last.pt", tmp_path / "student"))  # the student config names no clock
    assert p.env.cfg.gait_period == 0.7 and p.meta["gait_period"] == 0.7
    # the teacher's actions are residuals on the clock's swing: the student acts in the same space
    assert p.env.cfg.gait_feedforward == 1.0 and p.meta["gait_feedforward"] == 1.0
    assert p.env.observation_spec["proprio"].shape[-1] == 39
    out = unified.train(tiny(ck / "last.pt", tmp_path / "student", "collector.total_frames=40"))
    assert out["iteration"] == 1
    # and its evaluation env is rebuilt with the same clock from the student checkpoint's meta
    cfg = cfg_of("evaluate", [f"checkpoint={tmp_path / 'student' / 'last.pt'}", "categories=[randommix]", "levels=[0]",
                              "robots_per_cell=1", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}",
                              "video=false", "logger.backend=csv"])
    assert len(eval_run.evaluate(cfg)["episodes"]) == 1


def test_student_of_a_foot_scan_teacher_gets_the_teachers_scandots(teacher, tmp_path):
    """A teacher trained with env.foot_scan reads 222 scandot columns: its student's env (the
    config names no foot scan) computes them for it, its labels and critic run on them, the
    student checkpoint records the scan and its evaluation env is rebuilt with it. A student
    config asking for the scan under a teacher without it gets the teacher's 132 columns."""
    ck = tmp_path / "oracle"
    oracle_ppo.train(cfg_of("oracle_ppo", ENV + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={ck}", "env.foot_scan=true"]))
    p = unified.build(tiny(ck / "last.pt", tmp_path / "student"))
    assert p.env.cfg.foot_scan and p.meta["foot_scan"] is True and p.meta["obs_layout"]["scandots"] == (222,)
    assert p.teacher.networks.cfg.scandots_dim == 222
    td = p.env.reset()
    assert p.teacher.label(td.select(*p.teacher.in_keys).copy())["action_tea"].shape == (4, p.env.A)
    assert p.critic(td.clone())["state_value"].shape == (4, 1)
    out = unified.train(tiny(ck / "last.pt", tmp_path / "student", "collector.total_frames=40"))
    assert out["iteration"] == 1 and load_checkpoint(tmp_path / "student" / "last.pt")["meta"]["foot_scan"] is True
    cfg = cfg_of("evaluate", [f"checkpoint={tmp_path / 'student' / 'last.pt'}", "categories=[randommix]", "levels=[0]",
                              "robots_per_cell=1", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}",
                              "video=false", "logger.backend=csv"])
    assert len(eval_run.evaluate(cfg)["episodes"]) == 1
    plain = unified.build(tiny(teacher, tmp_path / "plain", "env.foot_scan=true"))
    assert not plain.env.cfg.foot_scan and plain.env.observation_spec["scandots"].shape[-1] == 132


def test_dagger_replay_trains_the_locomotion_on_the_aggregated_window(teacher, tmp_path):
    cfg = tiny(teacher, tmp_path, "dagger_iters=5", "dagger_replay.capacity=25", "dagger_replay.batch_size=8",
               "dagger_replay.steps=4")
    p = unified.build(cfg)
    assert unified.build(tiny(teacher, tmp_path)).replay is None  # off by default
    with pytest.raises(ValueError, match=r"dagger_replay.capacity must be >= 0 \(0: off\), got -1"):
        unified.build(tiny(teacher, tmp_path, "dagger_replay.capacity=-1"))
    with pytest.raises(ValueError, match="dagger_replay.steps must be a positive integer, got 0"):
        unified.build(tiny(teacher, tmp_path, "dagger_replay.capacity=8", "dagger_replay.steps=0"))
    for it in range(2):
        with torch.no_grad():
            data = p.collect_env.rollout(10, p.student.policy, break_when_any_done=False)
        stats = unified.update(p, data, iteration=it, cfg=cfg)
        assert torch.isfinite(torch.tensor(stats["loss/replay_im_action"]))
    assert len(p.replay) == 25  # 2 x 40 steps through a 25-step window
    # the window holds the teacher's labels of the latest steps
    assert torch.equal(p.replay.buffer.storage[:25]["action_tea"].sort(0).values,
                       data["action_tea"].reshape(-1, data["action_tea"].shape[-1])[-25:].sort(0).values)


def test_the_dagger_replay_window_is_checkpointed_and_restored(teacher, tmp_path):
    """A resumed run samples the same aggregated DAgger data as the run that wrote the checkpoint."""
    rp = ["dagger_replay.capacity=30", "dagger_replay.batch_size=8", "dagger_replay.steps=2"]
    unified.train(tiny(teacher, tmp_path, "collector.total_frames=80", *rp))
    state = load_checkpoint(tmp_path / "last.pt")
    assert state["replay"]["capacity"] == 30
    resumed = unified.build(tiny(teacher, tmp_path, "collector.total_frames=120", "checkpoint.resume=auto", *rp))
    assert len(resumed.replay) == 30  # two 40-step batches through a 30-step window
    saved = resumed.replay.state_dict()
    assert torch.equal(saved["generator"], state["replay"]["generator"])
    window = resumed.replay.buffer.storage[:30]
    assert set(window.keys()) == {"z_uni", "proprio", "delta_g0", "goal_next", "action_tea"}
    fresh = unified.build(tiny(teacher, tmp_path / "fresh", *rp))
    fresh.replay.load_state_dict(state["replay"])
    assert (fresh.replay.buffer.storage[:30] == window).all()
    with pytest.raises(ValueError, match="saved window holds 30 steps, this one 20"):
        unified.build(tiny(teacher, tmp_path, "collector.total_frames=120", "checkpoint.resume=auto",
                           "dagger_replay.capacity=20"))


def test_a_branch_starts_from_another_runs_state_with_its_own_random_streams(teacher, tmp_path):
    """checkpoint.branch: weights, optimisers, curriculum, replay window and counters carried over;
    torch, numpy, env and window-sampling streams from this run's env.seed; a new logger run."""
    rp = ["dagger_replay.capacity=30", "dagger_replay.batch_size=8", "dagger_replay.steps=2"]
    src = tmp_path / "src"
    unified.train(tiny(teacher, src, "collector.total_frames=80", *rp))
    state = load_checkpoint(src / "last.pt")
    branch = [f"checkpoint.branch={src / 'last.pt'}", "env.seed=7", "hlm.enabled=false", *rp]
    p = unified.build(tiny(teacher, tmp_path / "b", "collector.total_frames=120", *branch))
    assert (p.iteration, p.frames, p.run_id) == (2, 80, None)
    for mine, saved in ((p.student.perception, state["perception"]), (p.student.actor, state["actor"]),
                        (p.critic_nets, state["critic"]), (p.vae, state["vae"])):
        for k, v in saved.items():
            assert torch.equal(mine.state_dict()[k], v), k
    assert p.optim.state_dict()["state"][0]["step"] == state["optim"]["state"][0]["step"]
    assert p.env.curriculum.state_dict().keys() == state["env"]["curriculum"].keys()
    assert p.env.global_steps == state["env"]["global_steps"]
    assert p.env.rng.bit_generator.state != state["env"]["rng"]  # env.seed 7's stream, not the source's
    fresh = unified.build(tiny(teacher, tmp_path / "fresh", *rp))
    fresh.replay.load_state_dict(state["replay"])
    assert len(p.replay) == 30 and (p.replay.buffer.storage[:30] == fresh.replay.buffer.storage[:30]).all()
    assert not torch.equal(p.replay._gen.get_state(), state["replay"]["generator"])
    assert not torch.equal(torch.get_rng_state(), state["rng"]["torch"])
    info = p.meta["branched_from"]
    assert info["checkpoint"] == str(src / "last.pt") and (info["iteration"], info["frames"]) == (2, 80)
    assert info["sha256"] == file_digest(src / "last.pt")
    # trained on, the branch writes its own checkpoint, which records where it came from and resumes exactly
    out = unified.train(tiny(teacher, tmp_path / "b", "collector.total_frames=120", *branch))
    assert out["iteration"] == 3 and out["frames"] == 120
    mine = load_checkpoint(tmp_path / "b" / "last.pt")
    assert mine["meta"]["branched_from"] == info and mine["config"]["hlm"]["enabled"] is False
    resumed = unified.build(tiny(teacher, tmp_path / "b", "collector.total_frames=160", "checkpoint.resume=auto",
                                 *branch))
    assert resumed.frames == 120 and resumed.meta["branched_from"] == info
    assert torch.equal(resumed.replay._gen.get_state(), mine["replay"]["generator"])
    assert load_checkpoint(src / "last.pt")["frames"] == 80  # the source is only read


def test_a_branch_from_a_missing_or_foreign_checkpoint_is_refused(teacher, tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint.branch: no checkpoint at .*nowhere.pt"):
        unified.build(tiny(teacher, tmp_path, f"checkpoint.branch={tmp_path / 'nowhere.pt'}"))
    src = tmp_path / "src"
    unified.train(tiny(teacher, src, "collector.total_frames=40"))
    with pytest.raises(Exception, match="perception"):
        unified.build(tiny(teacher, tmp_path / "b", f"checkpoint.branch={src / 'last.pt'}",
                           "student.perception=vanilla"))


RMA = ["student.perception=rmah", "student.locomotion=oracle", "hlm.enabled=false"]


def test_rma_student_acts_with_the_teachers_actor_frozen(teacher, tmp_path):
    """RMA (student.locomotion=oracle): the locomotion module is the teacher's actor with its
    weights; fed the teacher's own latents and goals it gives the teacher's action; an update
    trains the adapter (the privileged-latent term included) and leaves the actor as it was."""
    p = unified.build(tiny(teacher, tmp_path, *RMA))
    actor_net = p.student.actor.module[0].module
    for k, v in p.teacher.networks.actor.state_dict().items():
        assert torch.equal(actor_net.state_dict()[k], v), k
    assert not any(q.requires_grad for q in actor_net.parameters())
    assert p.meta["locomotion"] == "oracle" and p.meta["oracle_config"]["num_actions"] == p.env.A
    with torch.no_grad():
        data = p.collect_env.rollout(10, p.student.policy, break_when_any_done=False)
        p.teacher.label(data)
        fed = data.select("proprio").clone()
        fed.update({"z_uni": data["z_tea"], "priv_latent_uni": data["priv_latent_tea"],
                    "goals_uni": data["goals_tea"]})
        assert torch.allclose(p.student.actor.module[0](fed)["loc"], data["action_tea"], atol=1e-6)
    before = {k: q.detach().clone() for k, q in p.student.perception.named_parameters()}
    frozen = [q.detach().clone() for q in actor_net.parameters()]
    stats = unified.update(p, data, iteration=0, cfg=tiny(teacher, tmp_path, *RMA))
    assert stats["train/phase_rl"] == 0.0 and stats["loss/im_priv_latent"] > 0
    assert all(torch.equal(a, b) for a, b in zip(frozen, actor_net.parameters(), strict=True))
    same = [k for k, q in p.student.perception.named_parameters() if torch.equal(before[k], q)]
    assert all("delta" in k for k in same), same  # all but delta_g0's head, which the frozen oracle does not read


def test_rma_student_trains_resumes_and_evaluates(teacher, tmp_path):
    out = unified.train(tiny(teacher, tmp_path / "ck", "collector.total_frames=80", "dagger_iters=5", *RMA))
    assert out["iteration"] == 2
    resumed = unified.build(tiny(teacher, tmp_path / "ck", "collector.total_frames=120", "dagger_iters=5",
                                 "checkpoint.resume=auto", *RMA))
    assert resumed.iteration == 2
    state = load_checkpoint(tmp_path / "ck" / "last.pt")
    for k, v in state["actor"].items():  # still the teacher's
        assert torch.equal(v, resumed.student.actor.state_dict()[k]), k
    cfg = cfg_of("evaluate", [f"checkpoint={tmp_path / 'ck' / 'last.pt'}", "categories=[randommix]", "levels=[0]",
                              "robots_per_cell=2", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}",
                              "video=false", "logger.backend=csv"])
    assert len(eval_run.evaluate(cfg)["episodes"]) == 2


@pytest.mark.parametrize("extra,match", [
    (["student.perception=tcvit", "student.locomotion=oracle", "hlm.enabled=false"], "only rmah and rmab make"),
    (["student.perception=rmab", "student.locomotion=oracle", "hlm.enabled=true"], "set hlm.enabled=false"),
    (RMA + ["dagger_replay.capacity=100"], "set dagger_replay.capacity=0"),
    (["student.locomotion=frozen"], "unknown student.locomotion 'frozen'"),
])
def test_bad_rma_settings_are_refused(teacher, tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        unified.build(tiny(teacher, tmp_path, *extra))


def test_a_blind_rma_b_student_trains_and_evaluates_without_the_camera(teacher, tmp_path):
    """RMA-B reads no depth: its env renders none (env.depth=false), its checkpoint's layout has no
    depth, and its evaluation builds a blind env; a perception that reads depth is refused one."""
    blind = ["student.perception=rmab", "student.locomotion=oracle", "hlm.enabled=false", "env.depth=false"]
    p = unified.build(tiny(teacher, tmp_path / "ck", "collector.total_frames=40", *blind))
    assert not p.env.cfg.depth_enabled and "depth" not in p.collect_env.observation_spec.keys()
    assert "depth" not in p.meta["obs_layout"]
    unified.train(tiny(teacher, tmp_path / "ck", "collector.total_frames=40", *blind))
    cfg = cfg_of("evaluate", [f"checkpoint={tmp_path / 'ck' / 'last.pt'}", "categories=[randommix]", "levels=[0]",
                              "robots_per_cell=2", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}",
                              "video=false", "logger.backend=csv"])
    assert len(eval_run.evaluate(cfg)["episodes"]) == 2
    with pytest.raises(ValueError, match="perception 'rmah' reads depth"):
        unified.build(tiny(teacher, tmp_path / "other", *RMA, "env.depth=false"))


def test_the_cheap_update_trains_resumes_and_keeps_snapshots(teacher, tmp_path, monkeypatch):
    """experiment=student_h1's switches: one DAgger minibatch, the encoder on a fraction of the
    ticks (the features recorded while acting on the rest), slim policy snapshots."""
    cheap = ["dagger_iters=10", "dagger_minibatches=2", "minibatch_split=strided", "fused_adam=true",
             "dagger_epochs=1", "encoder_grad_fraction=0.25", "checkpoint.snapshot_every=1"]
    p = unified.build(tiny(teacher, tmp_path / "probe", *cheap))
    assert p.student.hold.feature_key == "perception_features" and p.optim.defaults["fused"]
    with torch.no_grad():
        data = p.collect_env.rollout(10, p.behaviour, break_when_any_done=False)
    assert data["perception_features"].shape == (4, 10, p.student.hold.feature_shape[0])
    before = [q.detach().clone() for q in p.student.perception.parameters()]
    stats = unified.update(p, data, iteration=0, cfg=tiny(teacher, tmp_path / "probe", *cheap))
    assert stats["train/phase_rl"] == 0.0 and torch.isfinite(torch.tensor(stats["loss/im_action"]))
    moved = [not torch.equal(a, b) for a, b in zip(before, p.student.perception.parameters(), strict=True)]
    assert all(moved), "every perception weight, the encoder's included, gets a gradient"
    # the strided minibatches are views of the batch: every world in exactly one of them
    seen = []

    def spy(student, mb, fraction, generator=None):
        seen.append(mb["proprio"][:, 0, 0])  # a world's first proprio entry identifies it
        return real_pass(student, mb, fraction, generator)

    real_pass = unified.student_pass
    monkeypatch.setattr(unified, "student_pass", spy)
    unified.update(p, data, iteration=1, cfg=tiny(teacher, tmp_path / "probe", *cheap))
    monkeypatch.undo()
    assert len(seen) == 2 and sorted(torch.cat(seen).tolist()) == sorted(data["proprio"][:, 0, 0].tolist())
    # a default student records nothing while acting
    plain = unified.build(tiny(teacher, tmp_path / "plain"))
    assert plain.student.hold.feature_key is None and not plain.optim.defaults.get("fused")

    out = unified.train(tiny(teacher, tmp_path / "run", "collector.total_frames=80", *cheap))
    assert out["iteration"] == 2
    snaps = sorted(p.name for p in (tmp_path / "run" / "snapshots").iterdir())
    assert snaps == ["frames000000040.pt", "frames000000080.pt"]
    slim = load_checkpoint(tmp_path / "run" / "snapshots" / "frames000000040.pt")
    assert slim["meta"]["kind"] == "student" and "optim" not in slim
    again = unified.train(tiny(teacher, tmp_path / "run", "collector.total_frames=120", "checkpoint.resume=auto", *cheap))
    assert again["iteration"] == 3 and (tmp_path / "run" / "snapshots" / "frames000000120.pt").is_file()


@pytest.mark.parametrize("extra,match", [
    ("encoder_grad_fraction=0", r"encoder_grad_fraction must be a number in \(0, 1\], got 0"),
    ("encoder_grad_fraction=1.5", r"encoder_grad_fraction must be a number in \(0, 1\], got 1.5"),
    ("encoder_grad_fraction=half", r"encoder_grad_fraction must be a number in \(0, 1\], got 'half'"),
    ("dagger_minibatches=0", r"dagger_minibatches must be null \(ppo.num_minibatches\) or an integer in \[1, "
                             r"env.num_envs=4\], got 0"),
    ("dagger_minibatches=5", r"dagger_minibatches .* got 5"),
    ("minibatch_split=shuffled", r"minibatch_split must be permute or strided, got 'shuffled'"),
])
def test_bad_cheap_update_settings_are_refused(teacher, tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        unified.build(tiny(teacher, tmp_path, extra))


def test_bad_snapshot_every_is_refused(teacher, tmp_path):
    with pytest.raises(ValueError, match=r"checkpoint.snapshot_every must be an integer >= 0 .*got -2"):
        unified.train(tiny(teacher, tmp_path, "checkpoint.snapshot_every=-2"))


def test_a_newly_registered_perception_network_is_a_student_perception(teacher, tmp_path, monkeypatch):
    """The recipe's one list of perception networks is the registry (PERCEPTION_BUILDERS): a
    network registered after the recipe was imported is accepted and trained; a name no one
    registered is refused, listing the registered ones."""
    from legoh_rl.modules.perception import PERCEPTION_BUILDERS, make_tcvit

    built = []

    def my_perception(cfg, keys=None):
        built.append(cfg)
        return make_tcvit(cfg, keys)

    with pytest.raises(ValueError, match=r"unknown student.perception 'mine'; valid: \[.*'tcvit'"):
        unified.validate(tiny(teacher, tmp_path / "refused", "student.perception=mine"))
    monkeypatch.setitem(PERCEPTION_BUILDERS, "mine", my_perception)
    out = unified.train(tiny(teacher, tmp_path / "ck", "student.perception=mine", "collector.total_frames=40"))
    assert out["iteration"] == 1 and built
    assert load_checkpoint(tmp_path / "ck" / "last.pt")["meta"]["perception"] == "mine"


# the stage-5 oracle's student trains on its teacher's last env: the base-height cap and more Gap worlds
REAL_PITS_ENV = {"base_height_error_cap": 0.1, "category_weights": [1.0, 1.5, 1.0, 2.5, 0.6]}


@pytest.mark.parametrize("name,teacher,robot,env", [
    ("student_h1_foot_scan", "checkpoints/oracle_h1_foot_scan.pt", "h1", {}),
    ("student_h1_real_pits", "checkpoints/oracle_h1_real_pits.pt", "h1", REAL_PITS_ENV),
    ("student_g1_foot_scan", "checkpoints/oracle_g1_foot_scan.pt", "g1", {}),
    ("student_g1_real_pits", "checkpoints/oracle_g1_trails.pt", "g1", REAL_PITS_ENV)])
def test_experiment_foot_scan_students_distil_the_oracles_without_feedforward(tmp_path, name, teacher, robot, env):
    """student_h1's recipe on the oracles without the gait feedforward (oracle_h1_foot_scan.pt,
    oracle_h1.pt, oracle_g1_trails.pt): the teacher reads its 222 scandots (foot scan), none acts on a
    scripted swing, and the students keep the H1 one's schedule and student with only the robot,
    the teacher and (stage 5's) the teacher's env settings changed."""
    root = RECIPES.parent
    cfg = cfg_of("unified", [f"experiment={name}", f"checkpoint.dir={tmp_path}"])
    base = cfg_of("unified", ["experiment=student_h1", f"checkpoint.dir={tmp_path}", f"env.robot={robot}"]
                  + [f"env.{k}={v}" for k, v in env.items()])
    assert cfg.teacher == teacher and (root / cfg.teacher).is_file()
    assert load_checkpoint(root / teacher)["meta"]["robot"] == robot == cfg.env.robot
    assert cfg.dagger_iters == cfg.hlm.warmup_iters == 3500 and cfg.collector.total_frames == 4500 * 64 * 24
    assert cfg.env == base.env and cfg.student == base.student
    for key, value in env.items():  # the teacher trained with them
        assert load_checkpoint(root / teacher)["config"]["env"][key] == value
    small = cfg_of("unified", [f"experiment={name}", f"checkpoint.dir={tmp_path}", f"teacher={root / cfg.teacher}",
                               "env.num_envs=8", "env.categories=[randommix]", "env.category_weights=null",
                               "env.variants=1", "env.num_threads=1", "logger.backend=csv"])
    p = unified.build(small)
    assert p.env.cfg.robot == robot and p.env.cfg.foot_scan and p.env.cfg.gait_feedforward == 0.0
    assert p.env.observation_spec["scandots"].shape[-1] == 222


def test_init_starts_a_fresh_student_from_a_student_policys_weights(teacher, tmp_path):
    """checkpoint.init: perception and locomotion weights from a student policy (a slim export here),
    everything else fresh (critic, VAE, optimiser, curriculum, counters); the run records where it
    started and keeps that record through its checkpoints and a resume."""
    src = tmp_path / "src"
    unified.train(tiny(teacher, src, "collector.total_frames=80"))
    export = tmp_path / "student.pt"
    export_policy(src / "last.pt", export)
    saved = load_checkpoint(export)
    init = [f"checkpoint.init={export}", "env.seed=5"]
    p = unified.build(tiny(teacher, tmp_path / "i", "collector.total_frames=120", *init))
    fresh = unified.build(tiny(teacher, tmp_path / "fresh", "env.seed=5"))
    assert (p.iteration, p.frames) == (0, 0) and p.optim.state_dict()["state"] == {}
    for mine, weights in ((p.student.perception, saved["perception"]), (p.student.actor, saved["actor"])):
        assert all(torch.equal(mine.state_dict()[k], v) for k, v in weights.items())
    trained = load_checkpoint(src / "last.pt")
    for mine, other, theirs in ((p.critic_nets, fresh.critic_nets, trained["critic"]), (p.vae, fresh.vae, trained["vae"])):
        assert all(torch.equal(mine.state_dict()[k], v) for k, v in other.state_dict().items())  # this seed's init
        assert not all(torch.equal(mine.state_dict()[k], v) for k, v in theirs.items())
    info = p.meta[unified.INIT_KEY]
    assert info == {"checkpoint": str(export), "sha256": file_digest(export), "experiment": None, "frames": 80,
                    "teacher_sha256": saved["meta"]["teacher_sha256"]}
    unified.train(tiny(teacher, tmp_path / "i", "collector.total_frames=120", *init))
    assert load_checkpoint(tmp_path / "i" / "last.pt")["meta"][unified.INIT_KEY] == info
    resumed = unified.build(tiny(teacher, tmp_path / "i", "collector.total_frames=160", "checkpoint.resume=auto", *init))
    assert resumed.frames == 120 and resumed.meta[unified.INIT_KEY] == info  # resumed, not initialised again


def test_init_starts_a_student_under_a_teacher_that_sees_more_terrain(teacher, tmp_path):
    """A student policy distilled from a teacher without the foot scan starts a run whose teacher
    reads the near and far foot scan (292 scandots against 132): the scandots are the teacher's
    input, not the student's, so only the student's own observations must match."""
    far = tmp_path / "far"
    oracle_ppo.train(cfg_of("oracle_ppo", ENV + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={far}",
                                                 "env.foot_scan=true", "env.foot_scan_far=true"]))
    src = tmp_path / "src"
    unified.train(tiny(teacher, src, "collector.total_frames=40"))
    assert load_checkpoint(src / "last.pt")["meta"]["obs_layout"]["scandots"] == (132,)
    p = unified.build(tiny(far / "last.pt", tmp_path / "run", f"checkpoint.init={src / 'last.pt'}"))
    assert p.meta["obs_layout"]["scandots"] == (292,)
    saved = load_checkpoint(src / "last.pt")
    assert all(torch.equal(p.student.actor.state_dict()[k], v) for k, v in saved["actor"].items())
    # what the student itself reads must still match: another gait clock is refused
    with pytest.raises(ValueError, match=r"does not fit this run: obs_layout: .*\(37,\).*\(39,\).*; gait_period"):
        unified.build(tiny(far / "last.pt", tmp_path / "clock", f"checkpoint.init={src / 'last.pt'}",
                           "env.gait_period=0.8"))


def test_init_refuses_what_cannot_start_a_student(teacher, tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint.init: no student policy at .*nowhere.pt"):
        unified.validate(tiny(teacher, tmp_path / "a", f"checkpoint.init={tmp_path / 'nowhere.pt'}"))
    with pytest.raises(ValueError, match="checkpoint.init .* and checkpoint.branch .* set one"):
        unified.validate(tiny(teacher, tmp_path / "b", f"checkpoint.init={teacher}", f"checkpoint.branch={teacher}"))
    with pytest.raises(ValueError, match=r"holds no student policy \(kind 'oracle'\)"):
        unified.build(tiny(teacher, tmp_path / "c", f"checkpoint.init={teacher}"))
    src = tmp_path / "src"
    unified.train(tiny(teacher, src, "collector.total_frames=40", "student.perception=vanilla"))
    with pytest.raises(ValueError, match="perception: checkpoint has 'vanilla', this run needs 'tcvit'"):
        unified.build(tiny(teacher, tmp_path / "d", f"checkpoint.init={src / 'last.pt'}"))


def test_the_g1_student_distilled_again_starts_from_the_previous_g1_student(tmp_path):
    """student_g1_real_pits_init: student_g1_real_pits (the stage-5 G1 oracle's env and teacher) from
    checkpoints/student_g1_foot_scan.pt's perception and locomotion weights, on a shorter schedule; the
    committed student fits the new teacher's env (the same observation layout and gait clock)."""
    root = RECIPES.parent
    cfg = cfg_of("unified", ["experiment=student_g1_real_pits_init", f"checkpoint.dir={tmp_path}"])
    base = cfg_of("unified", ["experiment=student_g1_real_pits", f"checkpoint.dir={tmp_path}"])
    assert cfg.checkpoint.init == "checkpoints/student_g1_foot_scan.pt" and cfg.teacher == base.teacher
    assert cfg.env == base.env and cfg.student == base.student and cfg.imitation == base.imitation
    assert cfg.dagger_iters == cfg.hlm.warmup_iters == 2000 and cfg.collector.total_frames == 3000 * 64 * 24
    small = cfg_of("unified", ["experiment=student_g1_real_pits_init", f"checkpoint.dir={tmp_path}",
                               f"teacher={root / cfg.teacher}", f"checkpoint.init={root / cfg.checkpoint.init}",
                               "env.num_envs=8", "env.categories=[randommix]", "env.category_weights=null",
                               "env.variants=1", "env.num_threads=1", "logger.backend=csv"])
    p = unified.build(small)
    saved = load_checkpoint(root / cfg.checkpoint.init)
    assert all(torch.equal(p.student.actor.state_dict()[k], v) for k, v in saved["actor"].items())
    assert p.meta[unified.INIT_KEY]["experiment"] == "student_g1_foot_scan"


def test_the_h1_student_of_the_stage9_oracle_starts_from_the_previous_h1_student(tmp_path):
    """student_h1_long_stride: student_h1_real_pits's env and student under the stage-9 oracle
    (checkpoints/oracle_h1.pt, 292 scandots), from checkpoints/student_h1_real_pits.pt's weights (a student of
    the 222-scandot stage-5 oracle), DAgger to 2,000 iterations, then PPO from action std 0.3."""
    root = RECIPES.parent
    cfg = cfg_of("unified", ["experiment=student_h1_long_stride", f"checkpoint.dir={tmp_path}"])
    base = cfg_of("unified", ["experiment=student_h1_real_pits", f"checkpoint.dir={tmp_path}"])
    assert cfg.teacher == "checkpoints/oracle_h1.pt" and base.teacher == "checkpoints/oracle_h1_real_pits.pt"
    assert cfg.checkpoint.init == "checkpoints/student_h1_real_pits.pt"
    assert cfg.env == base.env and cfg.imitation == base.imitation
    assert {**cfg.student, "ppo_join_std": None} == {**base.student} and cfg.student.ppo_join_std == 0.3
    assert cfg.dagger_iters == cfg.hlm.warmup_iters == 2000 and cfg.collector.total_frames == 3000 * 64 * 24
    teacher = load_checkpoint(root / cfg.teacher)
    assert teacher["meta"]["experiment"] == "oracle_h1_long_stride" and teacher["meta"]["foot_scan_far"]
    small = cfg_of("unified", ["experiment=student_h1_long_stride", f"checkpoint.dir={tmp_path}",
                               f"teacher={root / cfg.teacher}", f"checkpoint.init={root / cfg.checkpoint.init}",
                               "env.num_envs=8", "env.categories=[randommix]", "env.category_weights=null",
                               "env.variants=1", "env.num_threads=1", "logger.backend=csv"])
    p = unified.build(small)
    assert p.env.observation_spec["scandots"].shape[-1] == 292
    saved = load_checkpoint(root / cfg.checkpoint.init)
    assert saved["meta"]["obs_layout"]["scandots"] == (222,)
    assert all(torch.equal(p.student.actor.state_dict()[k], v) for k, v in saved["actor"].items())
    assert p.meta[unified.INIT_KEY]["experiment"] == "student_h1_real_pits"


def test_the_g1_ppo_join_run_starts_from_the_dagger_end_with_the_lower_std(tmp_path):
    """student_g1_ppo_join: student_g1_real_pits_init's env, teacher and student from its DAgger
    end's averaged weights (the committed snapshot), 100 iterations with the student acting alone,
    then PPO + L_im + L_hie with the action std set to 0.3 at the join, 1,000 iterations."""
    root = RECIPES.parent
    cfg = cfg_of("unified", ["experiment=student_g1_ppo_join", f"checkpoint.dir={tmp_path}"])
    base = cfg_of("unified", ["experiment=student_g1_real_pits_init", f"checkpoint.dir={tmp_path}"])
    assert cfg.teacher == base.teacher and cfg.env == base.env and cfg.imitation == base.imitation
    assert {**cfg.student, "ppo_join_std": None} == {**base.student} and cfg.student.ppo_join_std == 0.3
    assert cfg.dagger_iters == cfg.hlm.warmup_iters == 100 and cfg.dagger_beta0 == 0.0
    assert cfg.collector.total_frames == 1100 * 64 * 24
    assert unified.beta_at(0, cfg) == 0.0  # the student acts alone from the start
    init = load_checkpoint(root / cfg.checkpoint.init)
    assert init["frames"] == 3_072_000 and init["meta"]["experiment"] == "student_g1_real_pits_init"
    small = cfg_of("unified", ["experiment=student_g1_ppo_join", f"checkpoint.dir={tmp_path / 'run'}",
                               f"teacher={root / cfg.teacher}", f"checkpoint.init={root / cfg.checkpoint.init}",
                               "env.num_envs=8", "env.categories=[randommix]", "env.category_weights=null",
                               "env.variants=1", "env.num_threads=1", "logger.backend=csv"])
    p = unified.build(small)
    assert all(torch.equal(p.student.perception.state_dict()[k], v) for k, v in init["perception"].items())
