"""Staged schedules as data (legoh_rl/training/stages.py) and the committed experiments: stages run
in order, each resuming the last, finished ones are skipped, an interrupted one stops the chain;
every committed experiment expands to the settings its committed checkpoint was trained with."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf, open_dict

from legoh_rl.training.checkpoint import load_checkpoint, save_checkpoint
from legoh_rl.training.config_store import upgrade_recorded_config
from legoh_rl.training.schedules import inherited_schedule, recorded_schedule
from legoh_rl.training.stages import (
    Stage,
    parse_stages,
    run_experiment,
    stage_config,
    stage_settings,
)

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2", "logger.backend=csv"]
EXPERIMENTS = sorted((RECIPES / "config" / "experiment").glob("*.yaml"))


def cfg_of(name, overrides, stages=None):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        cfg = compose(config_name=name, overrides=overrides)
    if stages is not None:
        with open_dict(cfg):
            cfg.stages = stages
    return cfg


TWO = {"walk": {"frames": 64, "overrides": {"ppo": {"entropy_coeff": 0.002}}},
       "start": {"frames": 32, "overrides": {"env": {"cmd_speed": 0.3}}}}


def test_stages_are_ordered_by_their_end_and_null_drops_one():
    stages = parse_stages({"b": {"frames": 20}, "a": {"frames": 10, "keep_curriculum": False}, "c": None})
    assert stages == [Stage("a", 10, {}, False), Stage("b", 20, {}, True)]
    assert parse_stages(None) == []


@pytest.mark.parametrize("raw,message", [
    ({"bad name": {"frames": 1}}, "stage name 'bad name'"),
    ({"a": {"frames": 0}}, r"stage a: frames must be a positive integer .* got 0"),
    ({"a": {"frames": 2.5}}, "got 2.5"),
    ({"a": {"frames": 5}, "b": {"frames": 5}}, r"end at frames \[5, 5\]"),
    ({"a": {"frames": 5, "overides": {}}}, r"stage a: unknown keys \['overides'\]"),
    ({"a": {"frames": 5, "overrides": [1]}}, "stage a: overrides must be a mapping"),
    ([1, 2], "stages must be a mapping"),
])
def test_bad_stages_are_refused_by_name(raw, message):
    with pytest.raises(ValueError, match=message):
        parse_stages(raw)


def fake_train(calls, interrupt_at=None):
    """A recipe's train stand-in: records the config, writes a last.pt at the stage's end."""
    def train(cfg):
        calls.append(cfg)
        frames = int(cfg.collector.total_frames)
        if cfg.stage_name == interrupt_at:
            frames //= 2
        state = {"frames": frames, "meta": {"kind": "oracle", "stage": cfg.stage_name}, "networks": {}}
        save_checkpoint(Path(cfg.checkpoint.dir) / "last.pt", state)
        return {"frames": frames, **({"interrupted": 15} if cfg.stage_name == interrupt_at else {})}
    return train


def test_stages_chain_resume_skip_and_stop_on_a_signal(tmp_path):
    cfg = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path}", "checkpoint.init=/some/policy.pt"], TWO)
    calls = []
    out = run_experiment(cfg, fake_train(calls, interrupt_at="walk"), "oracle_ppo")
    assert out["interrupted"] == 15 and out["stage"] == "walk" and "policy" not in out
    first, second = calls
    assert first.checkpoint.dir == str(tmp_path / "stage1-start") and first.checkpoint.resume is None
    assert first.checkpoint.init == "/some/policy.pt" and first.collector.total_frames == 32
    assert first.env.cmd_speed == 0.3 and first.ppo.entropy_coeff == cfg.ppo.entropy_coeff
    assert second.checkpoint.dir == str(tmp_path / "stage2-walk")
    assert second.checkpoint.resume == str(tmp_path / "stage1-start" / "last.pt") and second.checkpoint.init is None
    assert second.env.cmd_speed == cfg.env.cmd_speed and second.ppo.entropy_coeff == 0.002  # only its own overrides
    assert "stages" not in second and second.stage_name == "walk"
    # the same command again: stage 1 is done, stage 2 goes on from its own checkpoint
    calls.clear()
    out = run_experiment(cfg, fake_train(calls), "oracle_ppo")
    assert [c.stage_name for c in calls] == ["walk"] and calls[0].checkpoint.resume == str(tmp_path / "stage2-walk" / "last.pt")
    assert Path(out["policy"]) == tmp_path / "policy.pt" and load_checkpoint(out["policy"])["meta"]["stage"] == "walk"
    calls.clear()
    run_experiment(cfg, fake_train(calls), "oracle_ppo")
    assert calls == []  # everything done: nothing trains, the policy is exported again


def test_stages_refuse_an_explicit_resume_and_a_missing_previous_stage(tmp_path):
    cfg = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path}", "checkpoint.resume=/x/last.pt"], TWO)
    with pytest.raises(ValueError, match="resumes its stages on its own"):
        run_experiment(cfg, fake_train([]), "oracle_ppo")
    cfg = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path}"], TWO)
    with pytest.raises(FileNotFoundError, match=r"stage walk starts from stage start's checkpoint"):
        stage_config(cfg, parse_stages(cfg.stages), 1)


def test_an_experiment_for_another_recipe_is_refused():
    cfg = cfg_of("unified", ["experiment=oracle_h1_trails"])
    with pytest.raises(ValueError, match=r"experiment 'oracle_h1_trails' is for recipes/oracle_ppo.py, not recipes/unified.py"):
        run_experiment(cfg, fake_train([]), "unified")


def test_a_staged_oracle_trains_every_stage_and_exports_its_policy(tmp_path):
    cfg = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path}", "experiment_name=tiny"], TWO)
    out = run_experiment(cfg, oracle_ppo.train, "oracle_ppo")
    one, two = load_checkpoint(tmp_path / "stage1-start" / "last.pt"), load_checkpoint(tmp_path / "stage2-walk" / "last.pt")
    assert (one["frames"], two["frames"]) == (32, 64) and two["iteration"] == 2
    assert one["config"]["env"]["cmd_speed"] == 0.3 and two["config"]["ppo"]["entropy_coeff"] == 0.002
    assert two["meta"]["experiment"] == "tiny" and two["meta"]["stage"] == "walk"
    policy = load_checkpoint(out["policy"])
    assert "optim" not in policy and policy["meta"] == two["meta"]
    for k, v in policy["networks"].items():
        assert torch.equal(v, two["networks"][k]), k
    again = run_experiment(cfg, oracle_ppo.train, "oracle_ppo")  # finished: nothing more
    assert load_checkpoint(tmp_path / "stage2-walk" / "last.pt")["frames"] == 64 and again["policy"] == out["policy"]


def _action_std(trainer):
    from legoh_rl.modules.distributions import GaussianHead

    (head,) = [m for m in trainer.actor.modules() if isinstance(m, GaussianHead)]
    return head.log_std.detach().exp()


def test_start_std_sets_the_std_where_a_stage_begins_and_never_on_its_own_resume(tmp_path):
    """model.start_std: stage 2 starts from stage 1's state with every action std at 0.25 (stage 1's
    is init_std, 1.0, and learned), a std under max_std that a gradient reaches again; resuming stage
    2's own last.pt keeps the std it saved; a start_std above max_std is refused before any work."""
    stages = {"start": {"frames": 32, "overrides": {}},
              "quiet": {"frames": 64, "overrides": {"model": {"start_std": 0.25, "max_std": 0.3}}}}
    cfg = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path}", "experiment_name=tiny", "model.init_std=1.0"], stages)
    run_experiment(cfg, oracle_ppo.train, "oracle_ppo")
    one = load_checkpoint(tmp_path / "stage1-start" / "last.pt")
    assert torch.allclose(one["networks"]["actor.head.log_std"].exp(), torch.ones(1), atol=0.05)  # init_std, barely moved
    parsed = parse_stages(cfg.stages)
    begin = stage_config(cfg, parsed, 1)
    with open_dict(begin):
        begin.checkpoint.resume = str(tmp_path / "stage1-start" / "last.pt")  # as when stage 2 began
        begin.checkpoint.dir = str(tmp_path / "probe")  # (stage 2's own folder holds its checkpoint by now)
    std = _action_std(oracle_ppo.build(begin))
    assert torch.allclose(std, torch.full_like(std, 0.25))
    two = load_checkpoint(tmp_path / "stage2-quiet" / "last.pt")
    saved = two["networks"]["actor.head.log_std"].exp()
    assert not torch.allclose(saved, torch.full_like(saved, 0.25))  # learned from there: a gradient reached it
    again = _action_std(oracle_ppo.build(stage_config(cfg, parsed, 1)))  # its own last.pt: the std it saved
    assert torch.equal(again, saved)
    bad = cfg_of("oracle_ppo", TINY + [f"checkpoint.dir={tmp_path / 'bad'}", "model.start_std=0.4", "model.max_std=0.3"])
    with pytest.raises(ValueError, match=r"model.start_std=0.4 is above model.max_std=0.3"):
        oracle_ppo.validate(bad)


def test_the_low_std_stage_is_stage5s_state_with_only_the_action_std_changed():
    """oracle_h1_low_std: stage 1 is the same copy of stage 5's whole 20.0M-frame state as
    oracle_h1_free_gait's; stage 2 trains to the control's 40M frames with the control's settings but
    the action std (set to 0.25, capped at 0.3)."""
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_low_std"])
    stages = parse_stages(cfg.stages)
    assert [s.name for s in stages] == ["real_pits", "low_std"]
    first, second = stage_config(cfg, stages, 0), stage_config(cfg, stages, 1)
    copy = load_checkpoint(ROOT / first.checkpoint.dir / "last.pt")
    free = cfg_of("oracle_ppo", ["experiment=oracle_h1_free_gait"])
    theirs = load_checkpoint(ROOT / stage_config(free, parse_stages(free.stages), 0).checkpoint.dir / "last.pt")
    assert copy["frames"] == theirs["frames"] == stages[0].frames
    assert copy["iteration"] == theirs["iteration"] and all(torch.equal(copy["networks"][k], theirs["networks"][k]) for k in theirs["networks"])
    control = cfg_of("oracle_ppo", ["experiment=oracle_h1_real_pits_long"])
    assert second.collector.total_frames == control.collector.total_frames == 40_000_000
    assert (second.model.start_std, second.model.max_std) == (0.25, 0.3)
    assert copy["networks"]["actor.head.log_std"].exp().min() > 0.5  # why: the std stood above its old ceiling
    for key in ("env", "ppo"):
        assert OmegaConf.to_container(second[key], resolve=True) == OmegaConf.to_container(control[key], resolve=True), key
    mine, theirs_model = OmegaConf.to_container(second.model), OmegaConf.to_container(control.model)
    assert {k: v for k, v in mine.items() if k not in ("start_std", "max_std")} == \
        {k: v for k, v in theirs_model.items() if k not in ("start_std", "max_std")}


def test_the_long_stride_stage_is_stage8s_state_with_only_gaps_joint_reference_lightened():
    """oracle_h1_long_stride: stage 1 is a copy of stage 8's (oracle_h1_far_scan's) whole final
    state; stage 2 trains it to 40M frames with stage 8's settings but gait_joint_ref at 0.25 on Gap
    worlds only and three PPO epochs."""
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_long_stride"])
    stages = parse_stages(cfg.stages)
    assert [s.name for s in stages] == ["far_scan", "long_stride"]
    first, second = stage_config(cfg, stages, 0), stage_config(cfg, stages, 1)
    copy = load_checkpoint(ROOT / first.checkpoint.dir / "last.pt")
    base = cfg_of("oracle_ppo", ["experiment=oracle_h1_far_scan"])
    theirs = load_checkpoint(ROOT / base.checkpoint.dir / "last.pt")
    assert copy["frames"] == theirs["frames"] == stages[0].frames
    assert all(torch.equal(copy["networks"][k], theirs["networks"][k]) for k in theirs["networks"])
    assert second.collector.total_frames == 40_000_000
    mine_env = OmegaConf.to_container(second.env, resolve=True)
    base_env = OmegaConf.to_container(base.env, resolve=True)
    assert mine_env.pop("category_reward_scales") == {"gap": {"gait_joint_ref": 0.25}}
    assert base_env.pop("category_reward_scales") == {}
    assert mine_env == base_env
    mine_ppo, base_ppo = OmegaConf.to_container(second.ppo), OmegaConf.to_container(base.ppo)
    assert (mine_ppo.pop("num_epochs"), base_ppo.pop("num_epochs")) == (3, 5)
    assert mine_ppo == base_ppo
    assert OmegaConf.to_container(second.model) == OmegaConf.to_container(base.model)


@pytest.mark.parametrize("path", EXPERIMENTS, ids=[p.stem for p in EXPERIMENTS])
def test_every_experiment_names_itself_and_its_recipe(path):
    recipe = OmegaConf.load(path).get("recipe")
    assert recipe in ("oracle_ppo", "unified"), f"{path.name} names no recipe"
    cfg = cfg_of(recipe, [f"experiment={path.stem}"])
    assert cfg.experiment_name == path.stem and cfg.recipe == recipe
    for stage in parse_stages(cfg.get("stages")):
        stage_settings(cfg, stage)  # every stage's overrides name existing settings


# (experiment, committed checkpoint): the experiment's last stage trains with the recorded settings
RECORDED = [("oracle_h1_randommix", "checkpoints/oracle_h1_randommix.pt"),
            ("oracle_g1_randommix", "checkpoints/oracle_g1.pt"),
            ("student_h1_randommix", "checkpoints/student_h1_randommix.pt"),
            ("student_h1_trails", "checkpoints/ablations/h1_lego_h_seed0.pt"),
            ("student_h1", "checkpoints/student_h1_clocked.pt"),
            ("student_h1_foot_scan", "checkpoints/student_h1_foot_scan.pt"),
            ("student_h1_real_pits", "checkpoints/student_h1_real_pits.pt"),
            ("student_h1_long_stride", "checkpoints/student_h1.pt"),
            ("oracle_h1_footholds", "checkpoints/oracle_h1_clocked.pt"),
            ("oracle_h1_foot_scan", "checkpoints/oracle_h1_foot_scan.pt"),
            ("oracle_h1_real_pits", "checkpoints/oracle_h1_real_pits.pt"),
            ("oracle_h1_long_stride", "checkpoints/oracle_h1.pt"),
            ("oracle_g1_trails", "checkpoints/oracle_g1_trails_clocked.pt"),
            ("oracle_g1_foot_scan", "checkpoints/oracle_g1_foot_scan.pt"),
            ("oracle_g1_real_pits", "checkpoints/oracle_g1_trails.pt"),
            ("g1_lego_h", "checkpoints/student_g1_clocked.pt"),
            ("student_g1_foot_scan", "checkpoints/student_g1_foot_scan.pt"),
            ("student_g1_real_pits_init", "checkpoints/student_g1_real_pits_init.pt"),
            ("student_g1_ppo_join", "checkpoints/student_g1.pt")]
SECTIONS = {"oracle_ppo": ("env", "ppo", "model"),
            "unified": ("env", "ppo", "student", "dagger_iters", "dagger_beta0", "dagger_decay_iters", "dagger_epochs",
                        "dagger_replay", "imitation", "hlm", "torch_threads")}


@pytest.mark.parametrize("name,checkpoint", RECORDED, ids=[r[0] for r in RECORDED])
def test_committed_experiments_expand_to_the_recorded_settings(name, checkpoint):
    state = load_checkpoint(ROOT / checkpoint)
    recorded = upgrade_recorded_config(state["config"])  # in today's layout
    cfg = cfg_of(OmegaConf.load(RECIPES / "config" / "experiment" / f"{name}.yaml").recipe, [f"experiment={name}"])
    stages = parse_stages(cfg.get("stages"))  # a single-stage experiment has none
    final = OmegaConf.to_container(stage_settings(cfg, stages[-1]) if stages else cfg, resolve=True)
    assert final["collector"]["total_frames"] == recorded["collector"]["total_frames"]
    inherits = final.get("feedforward_anneal") == "inherit"  # env.gait_feedforward is not read then
    for section in SECTIONS[cfg.recipe]:
        want, have = recorded[section], final[section]
        if isinstance(want, dict):  # keys added to the config after the run are not in its record
            have = {k: have[k] for k in want if not (inherits and section == "env" and k == "gait_feedforward")}
            want = {k: want[k] for k in have}
        assert have == want, section
    if inherits:  # the schedule read from checkpoint.init: the one the run was started with by hand, to its rounding
        init = ROOT / final["checkpoint"]["init"]
        have, want = inherited_schedule(load_checkpoint(init), init), recorded_schedule(state, checkpoint)
        assert have.gain == pytest.approx(want.gain, rel=1e-3)
        if want.anneal is None:  # started at gain 0 (oracle_h1_real_pits): nothing left to anneal
            assert have.anneal is None and want.gain == 0
        else:
            assert have.anneal[0] == want.anneal[0] == 0
            assert have.anneal[1] == pytest.approx(want.anneal[1], rel=1e-3)


def test_every_committed_checkpoint_names_the_experiment_that_made_it():
    committed = sorted((ROOT / "checkpoints").glob("*.pt"))
    assert len(committed) >= 5
    for path in committed:
        name = load_checkpoint(path)["meta"].get("experiment")
        assert name and (RECIPES / "config" / "experiment" / f"{name}.yaml").is_file(), path.name


def test_the_gpu_oracle_experiment_is_the_cpu_stage_on_warp_with_more_worlds():
    """oracle_h1_trails_gpu changes where the stage runs (Warp physics, CUDA, 4,096 worlds), not
    what it trains: the same init, rewards, curriculum, PPO settings, anneal and frame budget."""
    cpu = OmegaConf.to_container(cfg_of("oracle_ppo", ["experiment=oracle_h1_trails"]), resolve=True)
    gpu = OmegaConf.to_container(cfg_of("oracle_ppo", ["experiment=oracle_h1_trails_gpu"]), resolve=True)
    assert (gpu["device"], gpu["env"]["physics"], gpu["env"]["num_envs"]) == ("cuda", "warp", 4096)
    assert {k: v for k, v in gpu["env"].items() if k not in ("physics", "num_envs")} == {
        k: v for k, v in cpu["env"].items() if k not in ("physics", "num_envs")}
    for key in ("ppo", "model", "collector", "feedforward_anneal"):
        assert gpu[key] == cpu[key], key
    assert gpu["checkpoint"]["init"] == cpu["checkpoint"]["init"]
    assert gpu["checkpoint"]["dir"] != cpu["checkpoint"]["dir"]  # never the CPU run's directory


def test_the_gpu_g1_stage5_is_the_cpu_stage_with_cuda_networks_and_more_worlds(tmp_path):
    """oracle_g1_real_pits_gpu (recipes/gpu_kit.py's job) changes where G1's stage 5 runs (CUDA for
    the networks, C MuJoCo on 16 threads, 1,024 worlds, no collection during the update, csv logs),
    not what it trains; it builds and trains here with the device and sizes set back to a CPU's."""
    cpu = OmegaConf.to_container(cfg_of("oracle_ppo", ["experiment=oracle_g1_real_pits"]), resolve=True)
    gpu = OmegaConf.to_container(cfg_of("oracle_ppo", ["experiment=oracle_g1_real_pits_gpu"]), resolve=True)
    assert (gpu["device"], gpu["env"]["physics"], gpu["env"]["num_envs"], gpu["env"]["num_threads"]) == (
        "cuda", "mujoco", 1024, 16)
    assert {k: v for k, v in gpu["env"].items() if k not in ("num_envs", "num_threads")} == {
        k: v for k, v in cpu["env"].items() if k not in ("num_envs", "num_threads")}
    assert gpu["collector"] == {**cpu["collector"], "overlap": False} and cpu["collector"]["overlap"]
    for key in ("ppo", "model", "feedforward_anneal"):
        assert gpu[key] == cpu[key], key
    assert gpu["checkpoint"]["init"] == cpu["checkpoint"]["init"]
    assert gpu["checkpoint"]["dir"] != cpu["checkpoint"]["dir"]  # never the CPU run's directory
    small = cfg_of("oracle_ppo", ["experiment=oracle_g1_real_pits_gpu", "device=cpu", "env.num_envs=8",
                                  "env.num_threads=1", "torch_threads=1", "update_threads=1",
                                  "collector.total_frames=192", f"checkpoint.dir={tmp_path}"])
    out = run_experiment(small, oracle_ppo.train, "oracle_ppo")
    state = load_checkpoint(tmp_path / "last.pt")
    assert state["frames"] == 192 and state["meta"]["robot"] == "g1" and out["frames"] == 192

def test_the_g1_trail_oracle_is_the_h1_oracles_two_runs_as_one_schedule():
    """oracle_g1_trails stages the two H1 runs behind checkpoints/oracle_h1_clocked.pt (oracle_h1_trails,
    then oracle_h1_footholds to that export) for G1: each stage trains with the env, PPO and model
    settings of H1's run, but for the robot, G1's wider swing and the feedforward gain (one anneal
    over the whole schedule here, a new start per run there), and ends where H1's run ended."""
    g1 = cfg_of("oracle_ppo", ["experiment=oracle_g1_trails"])
    stages = parse_stages(g1.stages)
    assert [s.name for s in stages] == ["trails", "footholds"]
    ends = [load_checkpoint(ROOT / "runs" / "oracle_h1_trails" / "last.pt")["frames"]]
    ends.append(ends[0] + load_checkpoint(ROOT / "checkpoints" / "oracle_h1_clocked.pt")["frames"])
    for stage, name, end in zip(stages, ("oracle_h1_trails", "oracle_h1_footholds"), ends, strict=True):
        h1 = OmegaConf.to_container(cfg_of("oracle_ppo", [f"experiment={name}"]), resolve=True)
        mine = OmegaConf.to_container(stage_settings(g1, stage), resolve=True)
        assert stage.frames == end, stage.name
        assert (mine["env"]["robot"], mine["env"]["gait_amplitude"]) == ("g1", 0.45)
        differ = ("robot", "gait_amplitude", "gait_feedforward")
        assert {k: v for k, v in mine["env"].items() if k not in differ} == {
            k: v for k, v in h1["env"].items() if k not in differ}, stage.name
        for key in ("ppo", "model"):
            assert mine[key] == h1[key], (stage.name, key)
    assert stages[1].keep_curriculum is False  # H1's second run started afresh on levels 0-4
    assert g1.collector.total_frames == ends[1] and g1.checkpoint.init == "checkpoints/oracle_g1.pt"
    # one anneal line: the gain H1's second run started at (0.922) and its export's (0.580)
    anneal = list(g1.feedforward_anneal)
    gain = lambda frames: 1.0 - (frames - anneal[0]) / (anneal[1] - anneal[0])  # noqa: E731
    footholds = ROOT / "runs" / "oracle_h1_footholds" / "last.pt"
    assert abs(recorded_schedule(load_checkpoint(footholds), footholds).gain - gain(ends[0])) < 1e-3
    assert abs(load_checkpoint(ROOT / "checkpoints" / "oracle_h1_clocked.pt")["meta"]["gait_feedforward"] - gain(ends[1])) < 1e-3


def test_the_g1_lego_h_row_is_the_h1_lego_h_row_for_g1():
    g1 = OmegaConf.to_container(cfg_of("unified", ["experiment=g1_lego_h"]), resolve=True)
    h1 = OmegaConf.to_container(cfg_of("unified", ["experiment=h1_lego_h_seed", "env.seed=0"]), resolve=True)
    assert g1["teacher"] == "checkpoints/oracle_g1_trails_clocked.pt" and g1["env"]["robot"] == "g1"
    assert {k: v for k, v in g1["env"].items() if k != "robot"} == {k: v for k, v in h1["env"].items() if k != "robot"}
    for key in ("student", "hlm", "collector", "dagger_iters", "dagger_replay", "ppo", "imitation"):
        assert g1[key] == h1[key], key


def test_the_gpu_student_experiment_is_the_cpu_students_schedule_in_env_steps():
    """student_h1_trails_gpu changes where student_h1 runs (Warp, CUDA, 2,048 worlds) and keeps its
    schedule in env steps: the teacher's share decays, and PPO joins, at about the same step."""
    cpu = OmegaConf.to_container(cfg_of("unified", ["experiment=student_h1"]), resolve=True)
    gpu = OmegaConf.to_container(cfg_of("unified", ["experiment=student_h1_trails_gpu"]), resolve=True)
    assert (gpu["device"], gpu["env"]["physics"], gpu["env"]["num_envs"]) == ("cuda", "warp", 2048)
    assert {k: v for k, v in gpu["env"].items() if k not in ("physics", "num_envs", "num_threads")} == {
        k: v for k, v in cpu["env"].items() if k not in ("physics", "num_envs", "num_threads")}
    for key in ("student", "ppo", "imitation", "dagger_epochs", "dagger_minibatches", "encoder_grad_fraction",
                "minibatch_split", "teacher"):
        assert gpu[key] == cpu[key], key

    def steps(cfg, iters):
        return iters * cfg["env"]["num_envs"] * cfg["collector"]["steps_per_env"]

    for key in ("dagger_iters", "dagger_decay_iters"):
        assert 0.75 < steps(gpu, gpu[key]) / steps(cpu, cpu[key]) < 1.35, key
    assert gpu["hlm"]["warmup_iters"] == gpu["dagger_iters"] and cpu["hlm"]["warmup_iters"] == cpu["dagger_iters"]
    assert gpu["checkpoint"]["dir"] != cpu["checkpoint"]["dir"]


def test_the_g1_stage5_is_h1s_stage5_on_the_committed_g1_oracle():
    """oracle_g1_real_pits changes on G1 what oracle_h1_real_pits changed on H1 (the benchmark's pits,
    the base-height cap, the Gap weight), from a fixed file holding checkpoints/oracle_g1_foot_scan.pt's
    networks, at the gain 0 that run reached."""
    def env_of(name):
        return OmegaConf.to_container(cfg_of("oracle_ppo", [f"experiment={name}"]).env, resolve=True)

    g1, h1 = env_of("oracle_g1_real_pits"), env_of("oracle_h1_real_pits")
    g1_before, h1_before = env_of("oracle_g1_foot_scan"), env_of("oracle_h1_foot_scan")
    changed = {k for k in h1 if h1[k] != h1_before.get(k)}
    assert changed == {"pit_depths", "base_height_error_cap", "category_weights"}
    assert {k for k in g1 if g1[k] != g1_before.get(k)} == changed and all(g1[k] == h1[k] for k in changed)
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_g1_real_pits"])
    assert cfg.env.robot == "g1" and cfg.checkpoint.dir == "runs/oracle_g1_real_pits"
    init = load_checkpoint(ROOT / cfg.checkpoint.init)
    committed = load_checkpoint(ROOT / "checkpoints" / "oracle_g1_foot_scan.pt")
    assert init["networks"].keys() == committed["networks"].keys()
    assert all(torch.equal(init["networks"][k], committed["networks"][k]) for k in init["networks"])
    schedule = inherited_schedule(init, cfg.checkpoint.init)
    assert schedule.gain == 0.0 and schedule.anneal is None


def test_the_gpu_real_pits_student_is_the_cpu_students_schedule_on_cuda(tmp_path):
    """student_h1_real_pits_gpu (recipes/gpu_kit.py's student job) changes where student_h1_real_pits
    runs (CUDA for the networks, C MuJoCo and the march on 16 threads, 1,024 worlds) and keeps what it
    learns from: the teacher, the env, the networks, the losses, and the schedule in env steps; a PPO
    minibatch is the CPU run's 32 worlds. It builds and trains here with the device and sizes set back
    to a CPU's, through the DAgger phase into PPO + L_im + L_hie."""
    cpu = OmegaConf.to_container(cfg_of("unified", ["experiment=student_h1_real_pits"]), resolve=True)
    gpu = OmegaConf.to_container(cfg_of("unified", ["experiment=student_h1_real_pits_gpu"]), resolve=True)
    assert (gpu["device"], gpu["env"]["physics"], gpu["env"]["num_envs"], gpu["env"]["num_threads"]) == (
        "cuda", "mujoco", 1024, 16)
    assert {k: v for k, v in gpu["env"].items() if k not in ("num_envs", "num_threads")} == {
        k: v for k, v in cpu["env"].items() if k not in ("num_envs", "num_threads")}
    for key in ("teacher", "student", "imitation", "dagger_epochs", "encoder_grad_fraction", "minibatch_split"):
        assert gpu[key] == cpu[key], key
    assert {k: v for k, v in gpu["ppo"].items() if k != "num_minibatches"} == {
        k: v for k, v in cpu["ppo"].items() if k != "num_minibatches"}
    assert (gpu["env"]["num_envs"] // gpu["ppo"]["num_minibatches"]
            == cpu["env"]["num_envs"] // cpu["ppo"]["num_minibatches"])
    assert gpu["dagger_replay"]["capacity"] == cpu["dagger_replay"]["capacity"]  # the same window of env steps

    def steps(cfg, iters):
        return iters * cfg["env"]["num_envs"] * cfg["collector"]["steps_per_env"]

    for key in ("dagger_iters", "dagger_decay_iters"):
        assert 0.9 < steps(gpu, gpu[key]) / steps(cpu, cpu[key]) < 1.1, key
    assert 0.99 < gpu["collector"]["total_frames"] / cpu["collector"]["total_frames"] < 1.01
    assert gpu["collector"]["total_frames"] % steps(gpu, 1) == 0
    assert gpu["hlm"]["warmup_iters"] == gpu["dagger_iters"]
    assert gpu["checkpoint"]["dir"] != cpu["checkpoint"]["dir"] and gpu["logger"]["backend"] == "csv"
    small = cfg_of("unified", ["experiment=student_h1_real_pits_gpu", "device=cpu", "env.num_envs=4",
                               "env.num_threads=1", "torch_threads=1", "dagger_minibatches=2", "dagger_iters=1",
                               "dagger_decay_iters=1", "hlm.warmup_iters=1", "ppo.num_minibatches=2",
                               "collector.total_frames=192", "dagger_replay.steps=2", f"checkpoint.dir={tmp_path}"])
    out = run_experiment(small, unified.train, "unified")
    state = load_checkpoint(tmp_path / "last.pt")
    assert state["frames"] == 192 and out["frames"] == 192
    assert state["config"]["experiment_name"] == "student_h1_real_pits_gpu" and state["meta"]["robot"] == "h1"


def test_the_free_gait_stage_goes_on_from_stage5s_whole_state_with_the_gait_terms_off_on_pits():
    """oracle_h1_free_gait: stage 1 is done (a copy of oracle_h1_real_pits's last.pt at its end, the
    networks checkpoints/oracle_h1_real_pits.pt holds); stage 2 resumes it (optimiser, curriculum, random
    streams) to 40M frames with the env of stage 5 but for category_reward_scales, which zero the two
    gait-clock terms on Gap and Ditch; the control, oracle_h1_real_pits_long, ends at the same frames."""
    from legoh_rl.training.stages import _finished

    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_free_gait"])
    stages = parse_stages(cfg.stages)
    assert [s.name for s in stages] == ["real_pits", "free_gait"]
    first = stage_config(cfg, stages, 0)
    copy = load_checkpoint(ROOT / first.checkpoint.dir / "last.pt")
    exported = load_checkpoint(ROOT / "checkpoints" / "oracle_h1_real_pits.pt")
    assert copy["frames"] == stages[0].frames == exported["frames"] and _finished(first)
    assert all(torch.equal(copy["networks"][k], exported["networks"][k]) for k in exported["networks"])
    assert {"optim", "env", "rng"} <= set(copy)  # a whole training state, not a policy
    second = stage_config(cfg, stages, 1)
    # stage 2 resumes stage 1's state until it has one of its own (its committed last.pt, once trained)
    start = second.checkpoint.dir if (ROOT / second.checkpoint.dir / "last.pt").is_file() else first.checkpoint.dir
    assert Path(second.checkpoint.resume) in (ROOT / start / "last.pt", Path(start) / "last.pt")
    assert second.checkpoint.keep_curriculum and second.checkpoint.init is None
    free = OmegaConf.to_container(second.env, resolve=True)
    stage5 = OmegaConf.to_container(cfg_of("oracle_ppo", ["experiment=oracle_h1_real_pits"]).env, resolve=True)
    off = {"gait_contact": 0.0, "gait_joint_ref": 0.0}
    assert free.pop("category_reward_scales") == {"gap": off, "ditch": off}
    assert stage5.pop("category_reward_scales") == {} and free == stage5
    assert set(off) <= set(stage5["reward_overrides"])  # both terms are weighted in stage 5
    control = cfg_of("oracle_ppo", ["experiment=oracle_h1_real_pits_long"])
    assert control.collector.total_frames == second.collector.total_frames == 40_000_000
    for key in ("ppo", "model"):
        assert OmegaConf.to_container(second[key]) == OmegaConf.to_container(control[key]), key


@pytest.mark.parametrize("robot", ["h1", "g1"])
def test_a_long_stage_5_continues_its_committed_run_with_nothing_changed_but_the_frames(robot):
    """oracle_<robot>_real_pits_long resumes oracle_<robot>_real_pits's own folder (its committed
    last.pt, finished at 20M frames; H1's since continued to 40M, within one batch) to 40M, every
    other setting the same."""
    short = OmegaConf.to_container(cfg_of("oracle_ppo", [f"experiment=oracle_{robot}_real_pits"]), resolve=True)
    long = OmegaConf.to_container(cfg_of("oracle_ppo", [f"experiment=oracle_{robot}_real_pits_long"]), resolve=True)
    assert long.pop("experiment_name") == f"oracle_{robot}_real_pits_long"
    assert short.pop("experiment_name") == f"oracle_{robot}_real_pits"
    assert (short["collector"].pop("total_frames"), long["collector"].pop("total_frames")) == (20_000_000, 40_000_000)
    assert long == short  # the same run folder, logger name, env, networks and PPO
    state = load_checkpoint(ROOT / long["checkpoint"]["dir"] / "last.pt")
    batch = long["env"]["num_envs"] * long["collector"]["steps_per_env"]
    assert 20_000_000 <= state["frames"] < 40_000_000 + batch and state["meta"]["robot"] == robot


# Table 1 at convergence: the branch point is student_h1_real_pits' last.pt as committed in 41862d3
CONVERGED_BRANCH = ("41862d3", "runs/student_h1_real_pits/last.pt")


def test_table1_at_convergence_rows_differ_from_the_committed_student_only_in_what_they_ablate():
    """h1_lego_h_converged / h1_no_hlm_converged branch student_h1_real_pits after its DAgger phase and
    differ from it in the random streams and from each other in L_hie alone; h1_vanilla_converged is
    its whole schedule with the ConvGRU perception and no HLM (the paper's Vanilla row)."""
    base = OmegaConf.to_container(cfg_of("unified", ["experiment=student_h1_real_pits"]), resolve=True)
    rows = {name: OmegaConf.to_container(cfg_of("unified", [f"experiment={name}"]), resolve=True)
            for name in ("h1_lego_h_converged", "h1_no_hlm_converged", "h1_vanilla_converged")}
    lego, no_hlm, vanilla = rows.values()
    same = lambda a, b, skip: {k: v for k, v in a.items() if k not in skip} == {  # noqa: E731
        k: v for k, v in b.items() if k not in skip}
    run_keys = {"experiment_name", "logger", "checkpoint", "env"}
    assert same(lego, base, run_keys) and same(lego["env"], base["env"], {"seed"})
    assert lego["env"]["seed"] == 1 != base["env"]["seed"]
    assert same(no_hlm, lego, run_keys | {"hlm"}) and same(no_hlm["hlm"], lego["hlm"], {"enabled"})
    assert lego["hlm"]["enabled"] and not no_hlm["hlm"]["enabled"]
    assert lego["checkpoint"]["branch"] == no_hlm["checkpoint"]["branch"] == "runs/student_h1_real_pits/dagger_end.pt"
    assert lego["checkpoint"]["dir"] != no_hlm["checkpoint"]["dir"]
    assert same(vanilla, base, run_keys | {"student", "hlm"}) and vanilla["env"] == base["env"]
    assert vanilla["student"]["perception"] == "vanilla" and not vanilla["hlm"]["enabled"]
    assert vanilla["checkpoint"].get("branch") is None
    assert base["hlm"]["warmup_iters"] == base["dagger_iters"]  # L_hie waits for PPO: the DAgger phase is shared


def test_the_converged_rows_branch_point_is_in_gits_history(tmp_path):
    """The command in h1_lego_h_converged.yaml takes the branch point out of the history: the end of
    student_h1_real_pits' DAgger phase (iteration 3,513, 13 iterations into PPO + L_im + L_hie)."""
    commit, path = CONVERGED_BRANCH
    for row in ("h1_lego_h_converged", "h1_no_hlm_converged"):
        assert f"git show {commit}:{path} > runs/student_h1_real_pits/dagger_end.pt" in (
            RECIPES / "config" / "experiment" / f"{row}.yaml").read_text()
    blob = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, check=True).stdout
    (tmp_path / "dagger_end.pt").write_bytes(blob)
    state = load_checkpoint(tmp_path / "dagger_end.pt")
    assert (state["iteration"], state["frames"]) == (3513, 3513 * 64 * 24)
    assert state["meta"]["experiment"] == "student_h1_real_pits"
    cfg = cfg_of("unified", ["experiment=student_h1_real_pits"])
    assert cfg.dagger_iters <= state["iteration"] < cfg.dagger_iters + 20
