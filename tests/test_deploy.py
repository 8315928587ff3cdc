"""ONNX deployment (docs/deploy.md): export, metadata, onnxruntime policies against torch."""

import sys
import warnings
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from legoh_rl.training.checkpoint import load_checkpoint, save_checkpoint
from legoh_rl.training.evaluation import EvalProtocol
from legoh_rl.training.onnx_export import DeployError, export_onnx, student_modules
from legoh_rl.training.onnx_policy import OnnxModule, read_metadata, resolve_onnx
from legoh_rl.training.policies import load_policy

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import export_policy as export_recipe  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

ORACLE = ROOT / "checkpoints" / "oracle_h1.pt"
STUDENT = ROOT / "checkpoints" / "student_h1.pt"
TINY = EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=2, seed=0)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The committed oracle and student exported by the recipe's command line."""
    out = tmp_path_factory.mktemp("deploy")
    argv = sys.argv
    try:
        for src, dst in ((ORACLE, out / "oracle_h1.onnx"), (STUDENT, out / "student_h1.onnx")):
            sys.argv = ["export_policy.py", str(src), str(dst), "--format", "onnx"]
            export_recipe.main()
    finally:
        sys.argv = argv
    return out


def _deterministic_steps(env, policy, other, steps, carried=()):
    """Step ``env`` with ``policy`` and run ``other`` on the same observations, carrying ``other``'s
    own state keys (``carried``) from its previous output; yield both outputs each step."""
    td = env.reset()
    state = None
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            mine = policy(td.clone())
            theirs = td.clone()
            if state is not None:
                theirs.update(state)
            theirs = other(theirs)
            state = {k: theirs["next", k] for k in carried}
            yield td, mine, theirs
            _, td = env.step_and_maybe_reset(mine)


def test_oracle_graph_carries_the_meta_block_and_acts_like_the_checkpoint(exported):
    path = exported / "oracle_h1.onnx"
    assert sorted(p.name for p in exported.glob("oracle_h1*")) == ["oracle_h1.onnx"]
    info = read_metadata(path)
    assert info["meta"] == load_checkpoint(ORACLE)["meta"]  # robot, obs layout, gait clock, experiment
    assert info["graph"] == "oracle" and info["rate_hz"] == 50 and info["recurrent"] == {}
    assert [k for _, k in info["inputs"]] == ["scandots", "privileged", "proprio", "expert_goals"]
    env, policy, kind = load_policy(str(ORACLE), TINY, variants=1, num_threads=1)
    onnx_env, onnx_policy, onnx_kind = load_policy(str(path), TINY, variants=1, num_threads=1)
    assert (kind, onnx_kind) == ("oracle", "oracle (onnx)")
    # rebuilt from the metadata: no feedforward (none in the meta block) and the foot scan
    assert onnx_env.cfg.gait_feedforward == env.cfg.gait_feedforward == info["meta"].get("gait_feedforward", 0.0) == 0.0
    assert onnx_env.cfg.foot_scan and env.cfg.foot_scan and info["meta"]["foot_scan"]
    worst = max(float((a["action"] - b["action"]).abs().max())
                for _, a, b in _deterministic_steps(env, policy, onnx_policy, 100))
    assert worst < 1e-5, worst


def test_evaluating_the_oracle_graph_gives_the_checkpoints_table(exported, tmp_path):
    """The same benchmark loop on the .pt and its .onnx. The actions agree to ~1e-6 (above), not
    bit for bit (other matrix kernels), and contact dynamics amplify that over a 30 s episode (as
    they do for two identical worlds of one torch batch): outcomes are equal, times close."""
    def evaluate(checkpoint, out):
        with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
            cfg = compose(config_name="evaluate", overrides=[
                f"checkpoint={checkpoint}", "categories=[randommix]", "levels=[0]", "robots_per_cell=2",
                "variants=1", "num_threads=1", f"output_dir={out}", "video=false", "logger.backend=csv"])
        return eval_run.evaluate(cfg)

    torch_eval = evaluate(ORACLE, tmp_path / "pt")
    onnx_eval = evaluate(exported / "oracle_h1.onnx", tmp_path / "onnx")
    assert len(torch_eval["episodes"]) == len(onnx_eval["episodes"]) == 2
    mean = {name: {m: v[0] for m, v in out["rows"]["overall"].items()} for name, out in
            (("torch", torch_eval), ("onnx", onnx_eval))}
    assert mean["onnx"]["success"] == mean["torch"]["success"] == 100.0
    assert mean["onnx"]["traverse_rate"] == mean["torch"]["traverse_rate"]
    assert abs(mean["onnx"]["trail_completion"] - mean["torch"]["trail_completion"]) <= 100 / 7  # one goal
    for m, tol in (("ttf", 1.0), ("time_to_reach", 1.0), ("mev", 0.5)):
        assert abs(mean["onnx"][m] - mean["torch"][m]) <= tol, (m, mean)
    assert (tmp_path / "onnx" / "table.md").is_file()


def test_student_pair_acts_like_the_checkpoint_through_perception_ticks(exported):
    perception, locomotion = exported / "student_h1.perception.onnx", exported / "student_h1.locomotion.onnx"
    assert not (exported / "student_h1.onnx").exists() and perception.is_file() and locomotion.is_file()
    for name in ("student_h1.onnx", "student_h1.perception.onnx", "student_h1.locomotion.onnx"):
        assert resolve_onnx(exported / name) == {"perception": perception, "locomotion": locomotion}
    p_info, l_info = read_metadata(perception), read_metadata(locomotion)
    assert p_info["meta"] == l_info["meta"] == load_checkpoint(STUDENT)["meta"]
    assert (p_info["rate_hz"], l_info["rate_hz"]) == (10, 50)
    assert p_info["recurrent"] == {"perception_hidden": "perception_hidden_out"} and l_info["recurrent"] == {}
    assert [k for _, k in l_info["inputs"]] == ["z_uni", "proprio", "delta_g0", "goal_next"]

    env, policy, _ = load_policy(str(STUDENT), TINY, variants=1, num_threads=1)
    _, onnx_policy, kind = load_policy(str(exported / "student_h1.onnx"), TINY, variants=1, num_threads=1)
    assert kind == "student (tcvit, onnx)"
    carried = ["held_z_uni", "held_delta_g0", "held_goals_uni", "held_valid", "perception_hidden"]
    ticks, worst = 0, {}
    for td, mine, theirs in _deterministic_steps(env, policy, onnx_policy, 16, carried):
        ticks += int(td["perception_tick"].all())
        for k in ("action", "z_uni", "goal_next", ("next", "perception_hidden")):
            worst[k] = max(worst.get(k, 0.0), float((mine[k] - theirs[k]).abs().max()))
    assert ticks == 4  # steps 0, 5, 10, 15: the GRU state went through three hand-overs
    assert max(worst.values()) < 1e-5, worst


def test_perception_graph_zeroes_the_gru_state_at_an_episode_start(exported):
    module = OnnxModule(exported / "student_h1.perception.onnx")
    assert module.in_keys[-1] == "is_init" and ("next", "perception_hidden") in module.out_keys
    shapes = module.feature_shapes
    gen = torch.Generator().manual_seed(0)
    td = TensorDict({k: torch.rand(2, *shapes[n], generator=gen) for n, k in module.inputs}, batch_size=[2])
    fresh = td.clone()
    fresh["perception_hidden"][0] = 0.0
    td["is_init"] = torch.tensor([[True], [False]])
    out, ref = module(td.clone()), module(fresh)
    torch.testing.assert_close(out["z_uni"], ref["z_uni"])
    torch.testing.assert_close(out["next", "perception_hidden"], ref["next", "perception_hidden"])
    assert module._primer().primers["perception_hidden"].shape[-2:] == (1, 128)


def _fake_student(tmp_path, perception):
    meta = {**load_checkpoint(STUDENT)["meta"], "perception": perception}
    net, actor, _ = student_modules(meta)
    return save_checkpoint(tmp_path / f"{perception}.pt", {"meta": meta, "perception": net.state_dict(),
                                                           "actor": actor.state_dict()}), net


def test_a_feedforward_perception_exports_without_state_and_tcvit_ct_is_refused(tmp_path):
    src, net = _fake_student(tmp_path, "rmab")
    paths = export_onnx(src, tmp_path / "rmab.onnx")
    module = OnnxModule(paths["perception"])
    assert "is_init" not in module.in_keys and not hasattr(module, "make_tensordict_primer")
    assert read_metadata(paths["perception"])["recurrent"] == {}
    gen = torch.Generator().manual_seed(0)
    td = TensorDict({k: torch.randn(3, *module.feature_shapes[n], generator=gen) for n, k in module.inputs},
                    batch_size=[3])
    assert "proprio_history" in td.keys()
    with torch.no_grad():
        want = net(td.clone())
    got = module(td)
    for k in ("z_uni", "delta_g0", "goals_uni"):
        torch.testing.assert_close(got[k], want[k], atol=1e-5, rtol=1e-5)
    src, _ = _fake_student(tmp_path, "tcvit_ct")
    with pytest.raises(DeployError, match="causal-transformer"):
        export_onnx(src, tmp_path / "ct.onnx")


def test_a_frozen_oracle_rma_student_exports_and_acts_like_its_checkpoint(tmp_path):
    """An RMA student (student.locomotion=oracle): its locomotion graph is the oracle's actor
    reading the adapter's estimates, and the pair acts like the torch checkpoint."""
    oracle = load_checkpoint(ORACLE)
    meta = {**load_checkpoint(STUDENT)["meta"], "perception": "rmah", "locomotion": "oracle",
            "oracle_config": oracle["oracle_config"]}
    net, actor, _ = student_modules(meta)
    torch.manual_seed(0)
    for q in net.parameters():  # an untrained adapter, but not the default init
        q.data.normal_(0.0, 0.1)
    actor.module[0].module.load_state_dict({k[len("actor."):]: v for k, v in oracle["networks"].items()
                                            if k.startswith("actor.")})
    src = save_checkpoint(tmp_path / "rmah.pt", {"meta": meta, "perception": net.state_dict(),
                                                 "actor": actor.state_dict()})
    paths = export_onnx(src, tmp_path / "rmah.onnx")
    assert [k for _, k in read_metadata(paths["locomotion"])["inputs"]] == [
        "proprio", "z_uni", "priv_latent_uni", "goals_uni"]
    env, policy, _ = load_policy(str(src), TINY, variants=1, num_threads=1)
    _, onnx_policy, kind = load_policy(str(paths["perception"]), TINY, variants=1, num_threads=1)
    assert kind == "student (rmah, onnx)"
    carried = ["held_z_uni", "held_delta_g0", "held_goals_uni", "held_priv_latent_uni", "held_valid"]
    worst = 0.0
    for _, mine, theirs in _deterministic_steps(env, policy, onnx_policy, 8, carried):
        worst = max(worst, float((mine["action"] - theirs["action"]).abs().max()))
    assert worst < 1e-5


def test_missing_deploy_packages_say_what_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx -> ImportError
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(ImportError, match=r"legoh-rl\[deploy\]"):
        export_onnx(ORACLE, tmp_path / "o.onnx")
    monkeypatch.setattr(sys, "argv", ["export_policy.py", str(ORACLE), str(tmp_path / "o.onnx"), "--format", "onnx"])
    with pytest.raises(SystemExit, match=r"pip install 'legoh-rl\[deploy\]'"):
        export_recipe.main()
    (tmp_path / "x.onnx").write_bytes(b"not read")
    with pytest.raises(ImportError, match=r"legoh-rl\[deploy\]"):
        load_policy(str(tmp_path / "x.onnx"), TINY)


def test_onnx_paths_that_name_no_export_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"none\.perception\.onnx"):
        load_policy(str(tmp_path / "none.onnx"), TINY)
    plain = tmp_path / "plain.onnx"
    with warnings.catch_warnings():  # the TorchScript exporter's deprecation notice
        warnings.simplefilter("ignore")
        torch.onnx.export(torch.nn.Linear(2, 1), (torch.zeros(1, 2),), str(plain), dynamo=False)
    with pytest.raises(DeployError, match="not a legoh-rl policy export"):
        load_policy(str(plain), TINY)
    (tmp_path / "junk.onnx").write_bytes(b"junk")
    with pytest.raises(DeployError, match="not a readable ONNX graph"):
        read_metadata(tmp_path / "junk.onnx")
