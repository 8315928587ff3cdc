"""DAggerLoss (paper Eq. 1): hand-computed values, gradients, keys, [N, T] batches, padding."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn

from legoh_rl.objectives import DAggerLoss


def hand_batch():
    # 2 samples, latent 3, 2 goals x (cos, sin), 2 joints
    return TensorDict(
        z_tea=torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]),
        z_uni=torch.tensor([[1.0, 0.0, 3.0], [1.0, 1.0, -1.0]]),
        goals_tea=torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[0.6, 0.8], [1.0, 0.0]]]),
        goals_uni=torch.tensor([[[1.0, 0.0], [0.0, -1.0]], [[0.6, 0.8], [0.0, 1.0]]]),
        action_tea=torch.tensor([[0.5, -0.5], [2.0, 0.0]]),
        loc=torch.tensor([[0.0, -0.5], [0.0, 0.2]]),
        batch_size=[2],
    )


# by hand:
# latent  ||dz||^2: [0+4+0, 1+1+1] = [4, 3]                              -> mean 3.5
# goals   |d| = s1 (0,0,0,2) -> SmoothL1 (0,0,0,1.5) mean 0.375;
#         s2 (0,0,1,1) -> (0,0,0.5,0.5) mean 0.25                         -> mean 0.3125
# action  |d| = s1 (0.5,0) -> (0.125, 0) mean 0.0625; s2 (2,0.2) -> (1.5, 0.02) mean 0.76
#                                                                         -> mean 0.41125
LATENT, GOALS, ACTION = 3.5, 0.3125, 0.41125


def test_matches_hand_computation_with_weights():
    out = DAggerLoss(w1=2.0, w2=3.0, w3=4.0)(hand_batch())
    torch.testing.assert_close(out["loss_im_latent"], torch.tensor(2.0 * LATENT))
    torch.testing.assert_close(out["loss_im_goals"], torch.tensor(3.0 * GOALS))
    torch.testing.assert_close(out["loss_im_action"], torch.tensor(4.0 * ACTION))
    torch.testing.assert_close(out["im_latent"], torch.tensor(LATENT))
    torch.testing.assert_close(out["im_action"], torch.tensor(ACTION))
    loss = DAggerLoss()
    total = sum(v for k, v in loss(hand_batch()).items() if k.startswith("loss_"))
    torch.testing.assert_close(total, torch.tensor(LATENT + GOALS + ACTION))
    assert set(loss.out_keys) == set(loss(hand_batch()).keys())


def test_privileged_latent_term_is_off_by_default_and_hand_computed_when_on():
    td = hand_batch()
    assert "loss_im_priv_latent" not in DAggerLoss()(td).keys()  # w_priv = 0: the keys are not read
    # ||dp||^2: s1 (1, -2) -> 5; s2 (0, 0.5) -> 0.25; mean 2.625
    td["priv_latent_tea"] = torch.tensor([[1.0, 0.0], [0.0, 0.5]])
    td["priv_latent_uni"] = torch.tensor([[0.0, 2.0], [0.0, 0.0]])
    td["priv_latent_uni"].requires_grad_(True)
    out = DAggerLoss(w_priv=2.0)(td)
    torch.testing.assert_close(out["loss_im_priv_latent"], torch.tensor(2.0 * 2.625))
    torch.testing.assert_close(out["im_priv_latent"], torch.tensor(2.625))
    out["loss_im_priv_latent"].backward()  # d/dp_uni of 2 mean_b ||p_tea - p_uni||^2 = -2 (p_tea - p_uni)
    torch.testing.assert_close(td["priv_latent_uni"].grad, -2.0 * (td["priv_latent_tea"] - td["priv_latent_uni"]).detach())
    with pytest.raises(ValueError, match="w_priv"):
        DAggerLoss(w_priv=-1.0)


def test_gradients_reach_student_not_teacher():
    td = hand_batch()
    for key in ("z_tea", "goals_tea", "action_tea", "z_uni", "goals_uni", "loc"):
        td[key] = td[key].clone().requires_grad_(True)
    out = DAggerLoss()(td)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    for key in ("z_tea", "goals_tea", "action_tea"):
        assert td[key].grad is None
    # d/dz_uni of mean_b ||z_tea - z_uni||^2 = -2 (z_tea - z_uni) / B
    torch.testing.assert_close(td["z_uni"].grad, -(td["z_tea"] - td["z_uni"]).detach())
    assert td["loc"].grad.abs().sum() > 0 and td["goals_uni"].grad.abs().sum() > 0


def test_set_keys_remaps():
    td = hand_batch()
    td.rename_key_("loc", ("student", "mean"))
    td.rename_key_("z_tea", "oracle_latent")
    td["valid"] = torch.tensor([True, False])
    loss = DAggerLoss()
    loss.set_keys(action_uni=("student", "mean"), z_tea="oracle_latent", mask="valid")
    assert ("student", "mean") in loss.in_keys
    out = loss(td)
    torch.testing.assert_close(out["im_latent"], torch.tensor(4.0))  # sample 0 only
    torch.testing.assert_close(out["im_action"], torch.tensor(0.0625))
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(not_a_key="x")
    with pytest.raises(KeyError, match=r"key .*z_tea.* not found"):
        DAggerLoss()(td)


def test_nt_batch_and_padding_mask():
    g = torch.Generator().manual_seed(0)
    n, t = 3, 5

    def rand(*s):
        return torch.randn(*s, generator=g)

    td = TensorDict(
        z_tea=rand(n, t, 32), z_uni=rand(n, t, 32), goals_tea=rand(n, t, 3, 2),
        goals_uni=rand(n, t, 3, 2), action_tea=rand(n, t, 10), loc=rand(n, t, 10),
        batch_size=[n, t],
    )
    loss = DAggerLoss()
    out_nt = loss(td)
    out_flat = loss(td.reshape(-1))
    for k in out_nt.keys():
        torch.testing.assert_close(out_nt[k], out_flat[k])
    # pad: valid steps keep their values, padded steps hold garbage that must not count
    mask = torch.ones(n, t + 2, 1, dtype=torch.bool)  # (*B, 1) as torchrl's collector mask
    mask[:, t:] = False
    padded = TensorDict(
        {k: torch.cat([v, 1e3 * torch.ones(n, 2, *v.shape[2:])], 1) for k, v in td.items()},
        batch_size=[n, t + 2],
    )
    padded["loc"] = padded["loc"].requires_grad_(True)
    padded[("collector", "mask")] = mask
    loss.set_keys(mask=("collector", "mask"))
    out_pad = loss(padded)
    for k in out_nt.keys():
        torch.testing.assert_close(out_pad[k], out_nt[k])
    out_pad["loss_im_action"].backward()
    assert (padded["loc"].grad[:, t:] == 0).all() and padded["loc"].grad[:, :t].abs().sum() > 0
    # a missing mask key means "all valid"; a wrong-shaped mask is an error
    padded[("collector", "mask")] = torch.ones(n, t + 2, 2, dtype=torch.bool)
    with pytest.raises(ValueError, match="does not match the batch shape"):
        loss(padded)


def test_student_network_is_run_and_input_untouched():
    torch.manual_seed(0)
    net = TensorDictModule(nn.Linear(4, 32 + 6 + 10), in_keys=["obs"], out_keys=["feat"])

    def split(feat):
        return feat[..., :32], feat[..., 32:38].unflatten(-1, (3, 2)), feat[..., 38:]

    student = TensorDictSequential(
        net, TensorDictModule(split, in_keys=["feat"], out_keys=["z_uni", "goals_uni", "loc"])
    )
    td = TensorDict(
        obs=torch.randn(6, 4), z_tea=torch.randn(6, 32), goals_tea=torch.randn(6, 3, 2),
        action_tea=torch.randn(6, 10),
        # stale, gradient-free rollout values that must be ignored
        z_uni=torch.zeros(6, 32), goals_uni=torch.zeros(6, 3, 2), loc=torch.zeros(6, 10),
        batch_size=[6],
    )
    loss = DAggerLoss(student)
    out = loss(td)
    fresh = student(td.clone())
    ref = DAggerLoss()(fresh)
    for k in out.keys():
        torch.testing.assert_close(out[k], ref[k])
    assert torch.equal(td["loc"], torch.zeros(6, 10)) and "feat" not in td.keys()
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    assert net.module.weight.grad.abs().sum() > 0
    assert any(p is net.module.weight for p in loss.parameters())


def test_zero_weight_term_is_skipped_and_bad_values_raise():
    td = hand_batch().exclude("goals_tea", "goals_uni")
    out = DAggerLoss(w2=0.0)(td)
    assert "loss_im_goals" not in out.keys()
    torch.testing.assert_close(out["loss_im_latent"], torch.tensor(LATENT))
    with pytest.raises(ValueError, match="w1 must be a finite number >= 0"):
        DAggerLoss(w1=-1.0)
    with pytest.raises(ValueError, match="reduction"):
        DAggerLoss(reduction="max")
    bad = hand_batch()
    bad["loc"] = torch.zeros(2, 3)
    with pytest.raises(ValueError, match="same shape"):
        DAggerLoss()(bad)


def test_reduction_none_and_sum():
    per = DAggerLoss(reduction="none")(hand_batch())
    torch.testing.assert_close(per["loss_im_latent"], torch.tensor([4.0, 3.0]))
    torch.testing.assert_close(per["loss_im_action"], torch.tensor([0.0625, 0.76]))
    tot = DAggerLoss(reduction="sum")(hand_batch())
    torch.testing.assert_close(tot["loss_im_goals"], torch.tensor(0.625))
