"""Oracle networks by name (``model.network``, ``ORACLE_NETWORKS``): a registered class trains
through the oracle recipe, is saved, reloaded by name and exported to ONNX; the default, ``mlp``,
is the paper's ``OracleNetworks`` and committed checkpoints, which record no name, load as it."""

import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from torch import nn

from legoh_rl.modules.configs import OracleConfig
from legoh_rl.modules.oracle import (
    ORACLE_NETWORKS,
    OracleActorNet,
    OracleNetworks,
    make_oracle_networks,
    register_oracle_network,
)
from legoh_rl.training.builders import oracle_networks
from legoh_rl.training.checkpoint import export_policy, load_checkpoint
from legoh_rl.training.evaluation import EvalProtocol
from legoh_rl.training.policies import load_policy

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2", "logger.backend=csv",
        "model.layers=[16]"]
CFG = OracleConfig(proprio_dim=7, num_actions=4, privileged_dim=5, scandots_dim=6, actor_layers=(16,),
                   critic_layers=(16,))


class SkipActor(OracleActorNet):
    """The paper's actor plus a linear skip from its input to the action means."""

    def __init__(self, cfg: OracleConfig) -> None:
        super().__init__(cfg)
        self.skip = nn.Linear(sum(self.dims), cfg.num_actions)

    def forward(self, proprio, z_tea, priv_latent, expert_goals):
        loc, scale = super().forward(proprio, z_tea, priv_latent, expert_goals)
        return loc + self.skip(torch.cat([proprio, z_tea, priv_latent, expert_goals.flatten(-2)], dim=-1)), scale


class SkipOracle(OracleNetworks):
    """A user's oracle: the paper's encoders and critic, :class:`SkipActor` as the actor."""

    actor_class = SkipActor


@pytest.fixture
def skip_registered():
    register_oracle_network("test_skip", SkipOracle)
    yield "test_skip"
    ORACLE_NETWORKS.pop("test_skip")


def cfg_of(overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name="oracle_ppo", overrides=overrides)


def test_a_registered_network_trains_saves_reloads_and_exports(skip_registered, tmp_path):
    ck = tmp_path / "ck"
    done = oracle_ppo.train(cfg_of(TINY + [f"model.network={skip_registered}", "collector.total_frames=64",
                                           f"checkpoint.dir={ck}"]))
    assert done["iteration"] == 2
    state = load_checkpoint(ck / "last.pt")
    assert state["oracle_config"]["network"] == "test_skip"
    assert any(k.startswith("actor.skip.") for k in state["networks"])
    networks = oracle_networks(state)  # rebuilt by the name the checkpoint records
    assert type(networks) is SkipOracle and type(networks.actor) is SkipActor
    for k, v in networks.state_dict().items():
        assert torch.equal(v, state["networks"][k]), k
    # the evaluation's loader and the ONNX export build it by name too
    slim = export_policy(ck / "last.pt", tmp_path / "skip.pt")
    protocol = EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=1, seed=0)
    _, policy, kind = load_policy(str(slim), protocol, variants=1, num_threads=1)
    assert kind == "oracle" and any(isinstance(m, SkipActor) for m in policy.modules())
    pytest.importorskip("onnxruntime")
    from legoh_rl.training.onnx_export import export_onnx

    paths = export_onnx(slim, tmp_path / "skip.onnx")  # checks onnxruntime against torch on random inputs
    assert paths["oracle"].stat().st_size > 0
    # resuming it as another network is refused by name, before any weight is loaded
    with pytest.raises(ValueError, match=r"holds oracle network 'test_skip': set model.network=test_skip"):
        oracle_ppo.build(cfg_of(TINY + ["collector.total_frames=96", f"checkpoint.dir={ck}",
                                        "checkpoint.resume=auto"]))


def test_the_default_is_the_papers_network_and_checkpoints_without_a_name_load_as_it():
    assert ORACLE_NETWORKS["mlp"] is OracleNetworks and CFG.network == "mlp"
    torch.manual_seed(0)
    built = make_oracle_networks(CFG)
    torch.manual_seed(0)
    paper = OracleNetworks(CFG)
    assert type(built) is OracleNetworks
    assert all(torch.equal(a, b) for a, b in zip(built.state_dict().values(), paper.state_dict().values(), strict=True))
    state = load_checkpoint(ROOT / "checkpoints" / "oracle_h1_clocked.pt")
    assert "network" not in state["oracle_config"]  # made before the key existed
    assert type(oracle_networks(state)) is OracleNetworks  # load_state_dict is strict
    assert cfg_of([]).model.network == "mlp"


def test_unknown_or_incomplete_networks_are_refused_by_name(skip_registered):
    with pytest.raises(ValueError, match=r"unknown oracle network 'nope'; registered: \['mlp', 'test_skip'\]"):
        make_oracle_networks(OracleConfig(**{**CFG.__dict__, "network": "nope"}))
    with pytest.raises(ValueError, match=r"model.network='nope': unknown oracle network 'nope'"):
        oracle_ppo.validate(cfg_of(TINY + ["model.network=nope"]))
    with pytest.raises(ValueError, match=r"'test_skip' is already registered \(SkipOracle\)"):
        register_oracle_network("test_skip", OracleNetworks)
    register_oracle_network("test_skip", SkipOracle)  # the same class again is a no-op
    with pytest.raises(ValueError, match=r"oracle network 'x' must be an nn.Module subclass"):
        register_oracle_network("x", object)

    class NoCritic(nn.Module):
        def __init__(self, cfg):
            super().__init__()
            self.cfg = cfg

    register_oracle_network("test_no_critic", NoCritic)
    try:
        with pytest.raises(ValueError, match=r"'test_no_critic' \(.*NoCritic\) lacks \['scandot_encoder', "
                                             r"'priv_encoder', 'actor', 'critic', 'actor_class'\]"):
            make_oracle_networks(OracleConfig(**{**CFG.__dict__, "network": "test_no_critic"}))
    finally:
        ORACLE_NETWORKS.pop("test_no_critic")
