"""Oracle actor-critic, student locomotion actor and adaptation module."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import IndependentNormal, ProbabilisticActor, ValueOperator

from legoh_rl.modules import (
    AdaptationConfig,
    LocomotionConfig,
    OracleConfig,
    OracleNetworks,
    make_adaptation_module,
    make_locomotion_actor,
    make_oracle_actor,
    make_oracle_actor_critic,
)
from legoh_rl.modules.configs import HistoryEncoderConfig


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """Tiny batches: one intra-op thread avoids OpenMP stalls on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def oracle_inputs(cfg: OracleConfig, batch=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "proprio": torch.randn(batch, cfg.proprio_dim, generator=g),
            "scandots": torch.randn(batch, cfg.scandots_dim, generator=g),
            "privileged": torch.randn(batch, cfg.privileged_dim, generator=g),
            "expert_goals": torch.randn(batch, cfg.num_goals, 2, generator=g),
            "proprio_history": torch.randn(batch, 10, cfg.proprio_dim, generator=g),
        },
        batch_size=[batch],
    )


@pytest.mark.parametrize("num_actions", [10, 12])
def test_oracle_actor_critic_shapes(num_actions):
    cfg = OracleConfig(proprio_dim=7 + 3 * num_actions, num_actions=num_actions,
                       privileged_dim=8 + num_actions)
    actor, critic = make_oracle_actor_critic(cfg)
    assert isinstance(actor, ProbabilisticActor)
    assert isinstance(critic, ValueOperator)
    for key in ("z_tea", "priv_latent", "loc", "scale", "action", "action_log_prob"):
        assert key in actor.out_keys
    td = oracle_inputs(cfg)
    with set_exploration_type(ExplorationType.RANDOM):
        td = actor(td)
    td = critic(td)
    assert td["z_tea"].shape == (4, 32)
    assert td["z_tea"].abs().max() <= 1.0  # Tanh out
    assert td["priv_latent"].shape == (4, 20)
    assert td["action"].shape == (4, num_actions)
    assert actor.spec["action"].shape == (num_actions,)
    assert actor.spec["action"].is_in(td["action"][0])
    assert td["action_log_prob"].shape == (4,)
    assert td["state_value"].shape == (4, 1)
    # the log-prob is the diagonal Gaussian's
    dist = IndependentNormal(td["loc"], td["scale"])
    torch.testing.assert_close(td["action_log_prob"], dist.log_prob(td["action"]))
    # deterministic mode returns the mean
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        det = actor(oracle_inputs(cfg))
    torch.testing.assert_close(det["action"], det["loc"])


def test_oracle_initial_std_and_state_independence():
    cfg = OracleConfig(proprio_dim=37, num_actions=10, privileged_dim=18, init_std=0.5)
    actor, _ = make_oracle_actor_critic(cfg)
    td = actor(oracle_inputs(cfg))
    torch.testing.assert_close(td["scale"], torch.full((4, 10), 0.5))


@pytest.mark.parametrize("share", [False, True])
def test_oracle_gradients_reach_every_parameter(share):
    cfg = OracleConfig(proprio_dim=37, num_actions=10, privileged_dim=18, share_encoders=share)
    nets = OracleNetworks(cfg)
    actor, critic = make_oracle_actor_critic(cfg, networks=nets)
    with set_exploration_type(ExplorationType.RANDOM):
        td = critic(actor(oracle_inputs(cfg)))
    loss = td["loc"].sum() + td["action_log_prob"].sum() + td["state_value"].sum()
    loss.backward()
    for name, p in nets.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    own = {id(p) for p in actor.parameters()} & {id(p) for p in critic.parameters()}
    assert bool(own) == share  # separate critic encoders unless shared


def test_oracle_loc_bound():
    cfg = OracleConfig(proprio_dim=37, num_actions=10, privileged_dim=18, loc_bound=0.5)
    actor, _ = make_oracle_actor_critic(cfg)
    td = oracle_inputs(cfg)
    td["proprio"] = td["proprio"] * 100
    assert actor(td)["loc"].abs().max() <= 0.5


def test_oracle_runs_on_adaptation_estimate():
    cfg = OracleConfig(proprio_dim=37, num_actions=10, privileged_dim=18)
    nets = OracleNetworks(cfg)
    actor, _ = make_oracle_actor_critic(cfg, networks=nets)
    adaptation = make_adaptation_module(AdaptationConfig(proprio_dim=37))
    deploy = make_oracle_actor(nets, priv_latent_module=adaptation)
    td = oracle_inputs(cfg).exclude("privileged")
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = deploy(td)
    assert out["priv_latent_hat"].shape == (4, 20)
    assert "priv_latent" not in out.keys()
    # same oracle parameters, the estimate in place of the privileged encoder's latent
    ref_loc, _ = nets.actor(td["proprio"], nets.scandot_encoder(td["scandots"]),
                            out["priv_latent_hat"], td["expert_goals"])
    torch.testing.assert_close(out["loc"], ref_loc)
    assert {id(p) for p in nets.actor.parameters()} <= {id(p) for p in actor.parameters()}


def test_oracle_bad_input_names_key():
    cfg = OracleConfig(proprio_dim=37, num_actions=10, privileged_dim=18)
    actor, _ = make_oracle_actor_critic(cfg)
    td = oracle_inputs(cfg)
    td["expert_goals"] = torch.randn(4, 2, 2)
    with pytest.raises(ValueError, match="expert_goals"):
        actor(td)


@pytest.mark.parametrize("kind", ["conv", "mlp"])
def test_adaptation_module(kind):
    cfg = AdaptationConfig(proprio_dim=43, encoder=HistoryEncoderConfig(kind=kind))
    module = make_adaptation_module(cfg)
    td = TensorDict({"proprio_history": torch.randn(5, 3, 10, 43)}, batch_size=[5, 3])
    out = module(td)
    assert out["priv_latent_hat"].shape == (5, 3, 20)
    out["priv_latent_hat"].pow(2).sum().backward()
    for name, p in module.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_adaptation_history_too_short():
    with pytest.raises(ValueError, match="history length 3"):
        make_adaptation_module(AdaptationConfig(proprio_dim=37, history_len=3))


def test_locomotion_actor():
    cfg = LocomotionConfig(proprio_dim=43, num_actions=12)
    actor = make_locomotion_actor(cfg)
    g = torch.Generator().manual_seed(0)
    td = TensorDict(
        {
            "z_uni": torch.randn(6, 32, generator=g),
            "proprio": torch.randn(6, 43, generator=g),
            "delta_g0": torch.randn(6, 2, generator=g),
            "goal_next": torch.randn(6, 2, generator=g),
        },
        batch_size=[6],
    )
    with set_exploration_type(ExplorationType.RANDOM):
        out = actor(td)
    assert out["action"].shape == (6, 12)
    assert actor.spec["action"].shape == (12,)
    assert out["loc"].shape == out["scale"].shape == (6, 12)
    assert out["action_log_prob"].shape == (6,)
    assert torch.isfinite(out["action_log_prob"]).all()
    (out["loc"].sum() + out["action_log_prob"].sum()).backward()
    for name, p in actor.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    td["goal_next"] = torch.randn(6, 3)
    with pytest.raises(ValueError, match="goal_next"):
        actor(td)


def test_gaussian_head_std_ceiling():
    import math

    from legoh_rl.modules.distributions import GaussianHead

    head = GaussianHead(4, 3, init_std=1.0, max_std=0.5)
    with torch.no_grad():
        head.log_std.copy_(torch.log(torch.tensor([0.2, 0.5, 2.0])))
    loc, scale = head(torch.zeros(2, 4))
    assert torch.allclose(scale, torch.tensor([[0.2, 0.5, 0.5]] * 2))
    # above the ceiling the std gets no gradient from the scale
    scale.sum().backward()
    assert head.log_std.grad[2] == 0.0 and math.isclose(head.log_std.grad[0].item(), 2 * 0.2, rel_tol=1e-5)
    with pytest.raises(ValueError, match=r"max_std must exceed min_std \(0.0001\), got 0.0"):
        GaussianHead(4, 3, max_std=0.0)


def test_set_action_std_sets_every_head_and_refuses_what_it_cannot_set():
    from torch import nn

    from legoh_rl.modules.distributions import GaussianHead, set_action_std

    net = nn.Sequential(nn.Linear(3, 4), GaussianHead(4, 2, init_std=1.0, max_std=0.8))
    assert set_action_std(net, 0.3) == 0.3
    _, scale = net[1](torch.zeros(5, 4))
    assert torch.allclose(scale, torch.full((5, 2), 0.3))
    assert net[1].log_std.requires_grad  # it trains on from there
    with pytest.raises(ValueError, match=r"std 0.9 is outside the head's range \[0.0001, 0.8\]"):
        set_action_std(net, 0.9)
    with pytest.raises(ValueError, match="Linear has no GaussianHead"):
        set_action_std(nn.Linear(2, 2), 0.3)
