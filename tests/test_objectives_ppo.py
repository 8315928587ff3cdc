"""PPO builder (torchrl ClipPPOLoss + GAE), policy KL and the KL-adaptive learning rate."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import (
    IndependentNormal,
    NormalParamExtractor,
    ProbabilisticActor,
    ValueOperator,
)
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.utils import ValueEstimators

from legoh_rl.objectives import (
    AdaptiveKLScheduler,
    PPOConfig,
    gaussian_kl,
    make_ppo_loss,
    policy_kl,
)
from legoh_rl.objectives.ppo import minibatch_keys, rollout_kl

OBS, ACT = 3, 2


def make_actor_critic():
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(OBS, 2 * ACT), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(net, in_keys=["obs"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=IndependentNormal,
        return_log_prob=True,
    )
    critic = ValueOperator(nn.Linear(OBS, 1), in_keys=["obs"])
    return actor, critic


def rollout(actor, n=4, t=8):
    g = torch.Generator().manual_seed(1)
    td = TensorDict(obs=torch.randn(n, t, OBS, generator=g), batch_size=[n, t])
    with torch.no_grad():
        actor(td)  # writes loc, scale, action, action_log_prob (the collector's job)
    td["next"] = TensorDict(
        obs=torch.randn(n, t, OBS, generator=g),
        reward=torch.randn(n, t, 1, generator=g),
        done=torch.zeros(n, t, 1, dtype=torch.bool),
        terminated=torch.zeros(n, t, 1, dtype=torch.bool),
        batch_size=[n, t],
    )
    return td


def log_prob(actor, td):
    with torch.no_grad():
        return actor.get_dist(td.select("obs")).log_prob(td["action"])


def test_builder_uses_rsl_rl_defaults():
    actor, critic = make_actor_critic()
    loss, gae = make_ppo_loss(actor, critic)
    assert loss.clip_epsilon.item() == pytest.approx(0.2)
    assert loss.entropy_coeff.item() == pytest.approx(0.01)
    assert loss.critic_coeff.item() == pytest.approx(1.0)
    assert loss.clip_value.item() == pytest.approx(0.2)
    assert loss.loss_critic_type == "l2" and loss.normalize_advantage
    assert gae is loss.value_estimator
    assert gae.gamma.item() == pytest.approx(0.99) and gae.lmbda.item() == pytest.approx(0.95)
    td = rollout(actor)
    with torch.no_grad():
        gae(td)
    assert td["advantage"].shape == (4, 8, 1) and "value_target" in td.keys()
    out = loss(td)
    assert {"loss_objective", "loss_critic", "loss_entropy"} <= set(out.keys())
    with pytest.raises(ValueError, match="clip_epsilon"):
        PPOConfig(clip_epsilon=1.5)
    with pytest.raises(ValueError, match="learning_rate"):
        PPOConfig(learning_rate=1.0)


def test_ppo_step_raises_log_prob_of_positive_advantage_actions():
    actor, critic = make_actor_critic()
    loss, gae = make_ppo_loss(actor, critic, PPOConfig(normalize_advantage=False))
    td = rollout(actor)
    with torch.no_grad():
        gae(td)
    td["advantage"] = torch.ones(4, 8, 1)  # every taken action was better than expected
    before = log_prob(actor, td)
    opt = torch.optim.SGD(loss.parameters(), lr=0.05)
    out = loss(td)
    opt.zero_grad()
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    opt.step()
    after = log_prob(actor, td)
    assert after.mean() > before.mean()
    # and with a negative advantage the same step lowers it
    actor, critic = make_actor_critic()
    loss, gae = make_ppo_loss(actor, critic, PPOConfig(normalize_advantage=False))
    td = rollout(actor)
    with torch.no_grad():
        gae(td)
    td["advantage"] = -torch.ones(4, 8, 1)
    before = log_prob(actor, td)
    opt = torch.optim.SGD(loss.parameters(), lr=0.05)
    loss(td)["loss_objective"].backward()
    opt.step()
    assert log_prob(actor, td).mean() < before.mean()


def test_gaussian_kl_matches_torch():
    g = torch.Generator().manual_seed(0)
    m0, m1 = torch.randn(5, 3, generator=g), torch.randn(5, 3, generator=g)
    s0, s1 = torch.rand(5, 3, generator=g) + 0.2, torch.rand(5, 3, generator=g) + 0.2
    ref = torch.distributions.kl_divergence(
        torch.distributions.Normal(m0, s0), torch.distributions.Normal(m1, s1)
    ).sum(-1)
    torch.testing.assert_close(gaussian_kl(m0, s0, m1, s1), ref)
    # by hand, one joint: KL(N(0,1) || N(1,2)) = log 2 + (1 + 1) / 8 - 1/2
    val = gaussian_kl(torch.zeros(1), torch.ones(1), torch.ones(1), 2 * torch.ones(1))
    torch.testing.assert_close(val, torch.tensor(0.6931472 + 0.25 - 0.5))


def test_policy_kl_reads_old_params_from_batch():
    actor, _ = make_actor_critic()
    td = rollout(actor)
    snapshot = td.clone()
    assert policy_kl(actor, td).item() == pytest.approx(0.0, abs=1e-7)
    with torch.no_grad():
        actor.module[0].module[0].bias.add_(0.3)
    kl = policy_kl(actor, td)
    with torch.no_grad():
        new = actor(td.select("obs"))
    expected = gaussian_kl(td["loc"], td["scale"], new["loc"], new["scale"]).mean()
    assert torch.equal(kl, expected)  # the parameter network alone gives the full actor's values
    assert kl > 0
    assert (td == snapshot).all()  # the batch keeps the rollout loc/scale
    # padding mask: masked samples do not count
    mask = torch.zeros(4, 8, 1, dtype=torch.bool)
    mask[:, :3] = True
    td[("collector", "mask")] = mask
    expected = gaussian_kl(td["loc"], td["scale"], new["loc"], new["scale"])[:, :3].mean()
    torch.testing.assert_close(policy_kl(actor, td), expected)


def test_minibatch_keys_give_the_loss_what_the_whole_batch_gives():
    actor, critic = make_actor_critic()
    loss, gae = make_ppo_loss(actor, critic)
    keys = minibatch_keys(loss, "loc", "scale")
    assert keys == ["obs", "action", "action_log_prob", "advantage", "value_target", "state_value",
                    ("collector", "mask"), "shifted_valid", "loc", "scale"]
    td = rollout(actor)
    mask = torch.ones(4, 8, 1, dtype=torch.bool)
    mask[:, 6:] = False  # padded steps: the selection must keep the mask the loss honours
    td[("collector", "mask")] = mask
    td["unread"] = torch.full((4, 8, 1), float("nan"))
    with torch.no_grad():
        gae(td)
    flat = td.reshape(-1)
    small = td.select(*keys, strict=False).reshape(-1)
    assert "unread" not in small.keys() and ("next", "obs") not in small.keys(True)
    idx = torch.randperm(32, generator=torch.Generator().manual_seed(0))[:16]
    whole, part = loss(flat[idx]), loss(small[idx])
    for k in ("loss_objective", "loss_critic", "loss_entropy"):
        assert torch.equal(whole[k], part[k]), k
    whole_grads = torch.autograd.grad(whole["loss_objective"] + whole["loss_critic"], list(loss.parameters()))
    part_grads = torch.autograd.grad(part["loss_objective"] + part["loss_critic"], list(loss.parameters()))
    assert all(torch.equal(a, b) for a, b in zip(whole_grads, part_grads, strict=True))


def test_the_loss_output_holds_the_current_policy_and_otherwise_is_torchrls():
    actor, critic = make_actor_critic()
    loss, gae = make_ppo_loss(actor, critic)
    plain = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.01, critic_coeff=1.0, loss_critic_type="l2",
                        normalize_advantage=True, clip_value=True)
    plain.make_value_estimator(ValueEstimators.GAE, gamma=0.99, lmbda=0.95)
    assert loss.state_dict().keys() == plain.state_dict().keys()
    td = rollout(actor)
    with torch.no_grad():
        gae(td)
        actor.module[0].module[0].bias.add_(0.3)  # the current policy is not the rollout one
    out, ref = loss(td), plain(td)
    for k in ("loss_objective", "loss_critic", "loss_entropy", "clip_fraction", "kl_approx"):
        assert torch.equal(out[k], ref[k]), k
    grads = torch.autograd.grad(out["loss_objective"] + out["loss_critic"], list(actor.parameters()))
    ref_grads = torch.autograd.grad(ref["loss_objective"] + ref["loss_critic"], list(actor.parameters()))
    assert all(torch.equal(a, b) for a, b in zip(grads, ref_grads, strict=True))
    with torch.no_grad():
        now = actor(td.select("obs"))
    assert not out["policy_loc"].requires_grad
    assert torch.equal(out["policy_loc"], now["loc"]) and torch.equal(out["policy_scale"], now["scale"])
    # the KL from the loss output is policy_kl's, without its actor pass
    kl = rollout_kl(td, out["policy_loc"], out["policy_scale"])
    assert kl > 0 and torch.equal(kl, policy_kl(actor, td))
    mask = torch.zeros(4, 8, 1, dtype=torch.bool)
    mask[:, :3] = True
    td[("collector", "mask")] = mask
    assert torch.equal(rollout_kl(td, now["loc"], now["scale"]), policy_kl(actor, td))
    td[("collector", "mask")] = torch.ones(4, 8, 2, dtype=torch.bool)
    with pytest.raises(ValueError, match=r"mask \('collector', 'mask'\) of shape \(4, 8, 2\) does not match"):
        rollout_kl(td, now["loc"], now["scale"])
    with pytest.raises(KeyError, match=r"'loc' and 'scale'"):
        rollout_kl(td.exclude("loc"), now["loc"], now["scale"])


def test_adaptive_kl_scheduler():
    params = [nn.Parameter(torch.zeros(1))]
    opt = torch.optim.Adam([{"params": params}, {"params": [nn.Parameter(torch.zeros(1))]}], lr=1e-3)
    sched = AdaptiveKLScheduler(opt, target_kl=0.01)
    assert sched.step(0.03) == pytest.approx(1e-3 / 1.5)  # kl > 2 target: lower
    assert all(g["lr"] == pytest.approx(1e-3 / 1.5) for g in opt.param_groups)
    assert sched.step(torch.tensor(0.015)) == pytest.approx(1e-3 / 1.5)  # in band: keep
    assert sched.step(0.002) == pytest.approx(1e-3)  # kl < target / 2: raise
    assert sched.step(0.0) == pytest.approx(1e-3)  # rsl_rl only raises for kl > 0
    for _ in range(30):
        sched.step(1.0)
    assert sched.lr == pytest.approx(1e-5)  # clamped low
    for _ in range(30):
        sched.step(1e-4)
    assert sched.lr == pytest.approx(1e-2)  # clamped high
    assert opt.param_groups[1]["lr"] == pytest.approx(1e-2)
    state = sched.state_dict()
    sched.step(1.0)
    sched.load_state_dict(state)
    assert opt.param_groups[0]["lr"] == pytest.approx(1e-2)
    with pytest.raises(ValueError, match="non-finite KL"):
        sched.step(float("nan"))
    with pytest.raises(ValueError, match="target_kl"):
        AdaptiveKLScheduler(opt, target_kl=0.0)
