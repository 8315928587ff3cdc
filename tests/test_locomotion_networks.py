"""The student's locomotion networks by name (``student.network``, ``LOCOMOTION_NETWORKS``): a
registered class trains through the unified recipe, is reloaded by name, evaluated and exported
to ONNX; the default, ``mlp``, is the paper's ``LocomotionNet`` and committed student
checkpoints, which record no name, load as it."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from legoh_rl.modules.configs import LocomotionConfig
from legoh_rl.modules.locomotion import (
    LOCOMOTION_NETWORKS,
    LocomotionNet,
    make_locomotion_actor,
    make_locomotion_network,
    register_locomotion_network,
)
from legoh_rl.training.checkpoint import CheckpointError, export_policy, load_checkpoint
from legoh_rl.training.evaluation import EvalProtocol
from legoh_rl.training.onnx_export import student_modules
from legoh_rl.training.policies import load_policy
from legoh_rl.training.student import locomotion_network

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_unified import cfg_of, teacher, tiny  # noqa: E402, F401  (the module-scoped tiny oracle)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))
import unified  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

CFG = LocomotionConfig(proprio_dim=7, num_actions=4, latent_dim=3, layers=(16,))


class SkipLocomotion(LocomotionNet):
    """The paper's MLP plus a linear skip from its inputs to the action means."""

    def __init__(self, cfg: LocomotionConfig) -> None:
        super().__init__(cfg)
        self.skip = nn.Linear(sum(self.dims), cfg.num_actions)

    def forward(self, z_uni, proprio, delta_g0, goal_next):
        loc, scale = super().forward(z_uni, proprio, delta_g0, goal_next)
        return loc + self.skip(torch.cat([z_uni, proprio, delta_g0, goal_next], dim=-1)), scale


@pytest.fixture
def skip_registered():
    register_locomotion_network("test_skip", SkipLocomotion)
    yield "test_skip"
    LOCOMOTION_NETWORKS.pop("test_skip")


def test_a_registered_network_trains_reloads_evaluates_and_exports(teacher, skip_registered, tmp_path):  # noqa: F811
    ck = tmp_path / "ck"
    done = unified.train(tiny(teacher, ck, "collector.total_frames=80", f"student.network={skip_registered}"))
    assert done["iteration"] == 2
    state = load_checkpoint(ck / "last.pt")
    assert state["meta"]["locomotion_network"] == "test_skip" and locomotion_network(state["meta"]) == "test_skip"
    assert any(".skip." in k for k in state["actor"])
    _, actor, _ = student_modules(state["meta"])  # rebuilt by the name the checkpoint records
    actor.load_state_dict(state["actor"])  # strict
    net = actor.module[0].module
    assert type(net) is SkipLocomotion
    # the evaluation's loader builds it by name, and an evaluation runs on it
    slim = export_policy(ck / "last.pt", tmp_path / "skip.pt")
    protocol = EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=1, seed=0)
    _, policy, kind = load_policy(str(slim), protocol, variants=1, num_threads=1)
    assert kind.startswith("student") and any(isinstance(m, SkipLocomotion) for m in policy.modules())
    out = eval_run.evaluate(cfg_of("evaluate", [f"checkpoint={slim}", "categories=[randommix]", "levels=[0]",
                                                "robots_per_cell=2", "variants=1", "num_threads=1",
                                                f"output_dir={tmp_path / 'eval'}", "video=false",
                                                "logger.backend=csv"]))
    assert len(out["episodes"]) == 2 and Path(out["table"]).is_file()
    # the ONNX locomotion graph computes what the registered class computes in torch
    pytest.importorskip("onnxruntime")
    from legoh_rl.training.onnx_export import export_onnx, make_session

    paths = export_onnx(slim, tmp_path / "skip.onnx")
    session = make_session(paths["locomotion"])
    gen = torch.Generator().manual_seed(3)
    sizes = {"z_uni": net.dims[0], "proprio": net.dims[1], "delta_g0": net.dims[2], "goal_next": net.dims[3]}
    inputs = {name: torch.randn(5, d, generator=gen) for name, d in sizes.items()}
    names = [i.name for i in session.get_inputs()]
    assert sorted(names) == sorted(sizes), names
    (got,) = session.run(None, {n: inputs[n].numpy() for n in names})  # its one output: loc
    with torch.no_grad():
        want, _ = net(*inputs.values())
    np.testing.assert_allclose(got, want.numpy(), atol=1e-5)
    # resuming it as another network is refused naming both, before any weight is loaded
    with pytest.raises(CheckpointError, match=r"holds locomotion network 'test_skip', this run has "
                                              r"student.network=mlp: set student.network=test_skip"):
        unified.build(tiny(teacher, ck, "collector.total_frames=120", "checkpoint.resume=auto"))


def test_the_default_is_the_papers_network_and_checkpoints_without_a_name_load_as_it():
    assert LOCOMOTION_NETWORKS["mlp"] is LocomotionNet and CFG.network == "mlp"
    torch.manual_seed(0)
    built = make_locomotion_actor(CFG)
    torch.manual_seed(0)
    paper = LocomotionNet(CFG)
    assert type(built.module[0].module) is LocomotionNet
    assert all(torch.equal(a, b) for a, b in
               zip(built.module[0].module.state_dict().values(), paper.state_dict().values(), strict=True))
    # checkpoints from before runs recorded the network, and one that records it
    for name, recorded in (("ablations/h1_lego_h_seed0.pt", False), ("student_g1_clocked.pt", False), ("student_h1.pt", True), ("student_h1_real_pits.pt", True), ("student_g1.pt", True),
                           ("student_g1_foot_scan.pt", True), ("student_g1_real_pits_init.pt", True)):
        state = load_checkpoint(ROOT / "checkpoints" / name)
        assert ("locomotion_network" in state["meta"]) is recorded, name
        assert locomotion_network(state["meta"]) == "mlp"
        _, actor, _ = student_modules(state["meta"])
        actor.load_state_dict(state["actor"])  # strict
        assert type(actor.module[0].module) is LocomotionNet
    assert cfg_of("unified", []).student.network == "mlp"


def test_unknown_networks_are_refused_by_name(teacher, skip_registered):  # noqa: F811
    with pytest.raises(ValueError, match=r"unknown locomotion network 'nope'; registered: \['mlp', 'test_skip'\]"):
        make_locomotion_network(LocomotionConfig(**{**CFG.__dict__, "network": "nope"}))
    with pytest.raises(ValueError, match=r"student.network='nope': unknown locomotion network 'nope'; "
                                         r"registered: \['mlp', 'test_skip'\]"):
        unified.validate(tiny(teacher, "/tmp/unused", "student.network=nope"))
    with pytest.raises(ValueError, match=r"student.network=test_skip names the student's own locomotion network"):
        unified.validate(tiny(teacher, "/tmp/unused", "student.network=test_skip", "student.locomotion=oracle",
                              "student.perception=rmah", "hlm.enabled=false"))
    with pytest.raises(ValueError, match=r"'test_skip' is already registered \(SkipLocomotion\)"):
        register_locomotion_network("test_skip", LocomotionNet)
    register_locomotion_network("test_skip", SkipLocomotion)  # the same class again is a no-op
    with pytest.raises(ValueError, match=r"locomotion network 'x' must be an nn.Module subclass"):
        register_locomotion_network("x", object)
    with pytest.raises(ValueError, match=r"LocomotionConfig.network must be a registered network's name, got ''"):
        make_locomotion_network(LocomotionConfig(**{**CFG.__dict__, "network": ""}))
