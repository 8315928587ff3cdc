"""MaskedVAELoss (paper Eqs. 2-5): hand-computed values, masking, keys, padding, training."""

import math

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from legoh_rl.modules.masked_vae import MaskedVAE, MaskedVAEConfig, mask_joints
from legoh_rl.objectives import MaskedVAELoss


class StubEncoder(nn.Module):
    """mu = 2u - 1 (= the action for bounds +-1), logvar = (0, -1) for every sample."""

    def __init__(self):
        super().__init__()
        self.lin = nn.Linear(2, 2)
        self.logvar = nn.Parameter(torch.tensor([0.0, -1.0]))
        with torch.no_grad():
            self.lin.weight.copy_(2.0 * torch.eye(2))
            self.lin.bias.fill_(-1.0)

    def forward(self, u):
        return self.lin(u), self.logvar.expand(*u.shape[:-1], 2)


class StubDecoder(nn.Module):
    """u = 0.5 + 0.25 z, hence Dec(z) = 2u - 1 = 0.5 z in the action space."""

    def __init__(self):
        super().__init__()
        self.lin = nn.Linear(2, 2)
        with torch.no_grad():
            self.lin.weight.copy_(0.25 * torch.eye(2))
            self.lin.bias.fill_(0.5)

    def forward(self, z):
        return self.lin(z)


def stub_vae():
    vae = MaskedVAE(
        MaskedVAEConfig(action_dim=2, latent_dim=2, hidden_dim=4, action_low=-1.0, action_high=1.0)
    )
    vae.encoder = StubEncoder()
    vae.decoder = StubDecoder()
    return vae


A_TEA = torch.tensor([[0.8, -0.4], [0.2, 0.6]])
# KL per latent element 0.5 (mu^2 + exp(lv) - 1 - lv), lv = (0, -1), averaged over the 2 dims
KL = [
    0.5 * (0.5 * 0.64 + 0.5 * (0.16 + math.exp(-1.0))),
    0.5 * (0.5 * 0.04 + 0.5 * (0.36 + math.exp(-1.0))),
]
# reconstructions are compared in unit space, u = (a + 1) / 2 for bounds +-1:
# u_tea = 0.5 + 0.5 a and u_rec = 0.5 + 0.25 z with z = mu = a, so |d| = 0.25 |a| per joint,
# SmoothL1 (beta 1) = 0.5 d^2, summed over joints
SELF = [0.5 * 0.2**2 + 0.5 * 0.1**2, 0.5 * 0.05**2 + 0.5 * 0.15**2]
# a masked joint enters as 0 and decodes to u = 0.5: |d| = 0.5 |a_j| there, 0.25 |a_k| elsewhere
MASKED = {  # (sample, masked joint) -> per-sample SmoothL1 sum
    (0, 0): 0.5 * 0.4**2 + 0.5 * 0.1**2,
    (0, 1): 0.5 * 0.2**2 + 0.5 * 0.2**2,
    (1, 0): 0.5 * 0.1**2 + 0.5 * 0.15**2,
    (1, 1): 0.5 * 0.05**2 + 0.5 * 0.3**2,
}


def stub_loss(**kw):
    # auto_fit_bounds off: the hand numbers use the stub's bounds +-1
    return MaskedVAELoss(stub_vae(), sample_latent=False, auto_fit_bounds=False, **kw)


def test_matches_hand_computation():
    loss = stub_loss(mask_ratio=0.5, seed=123, w4=2.0, w5=3.0, w6=5.0)
    out = loss(TensorDict(action_tea=A_TEA, batch_size=[2]))
    # the loss draws its mask first from its seeded generator: replicate it
    _, jm = mask_joints(A_TEA, 0.5, torch.Generator().manual_seed(123))
    masked = [MASKED[(i, int(jm[i].nonzero()))] for i in range(2)]
    torch.testing.assert_close(out["vae_kl"], torch.tensor(sum(KL) / 2))
    torch.testing.assert_close(out["vae_self"], torch.tensor(sum(SELF) / 2))
    torch.testing.assert_close(out["vae_mask"], torch.tensor(sum(masked) / 2))
    torch.testing.assert_close(out["loss_vae_kl"], torch.tensor(2.0 * sum(KL) / 2))
    torch.testing.assert_close(out["loss_vae_self"], torch.tensor(3.0 * sum(SELF) / 2))
    torch.testing.assert_close(out["loss_vae_mask"], torch.tensor(5.0 * sum(masked) / 2))
    # ratio 0: the masked input is the teacher action itself
    out0 = stub_loss(mask_ratio=0.0)(
        TensorDict(action_tea=A_TEA, batch_size=[2])
    )
    torch.testing.assert_close(out0["vae_mask"], out0["vae_self"])
    # Kingma's latent-summed KL is twice the mean here (2 latent dims)
    out_sum = stub_loss(kl_reduction="sum")(
        TensorDict(action_tea=A_TEA, batch_size=[2])
    )
    torch.testing.assert_close(out_sum["vae_kl"], torch.tensor(sum(KL)))
    # joint-mean reconstruction is half the joint sum (2 joints)
    out_mean = stub_loss(recon_reduction="mean")(
        TensorDict(action_tea=A_TEA, batch_size=[2])
    )
    torch.testing.assert_close(out_mean["vae_self"], torch.tensor(sum(SELF) / 4))


def test_gradients_train_vae_not_teacher():
    torch.manual_seed(0)
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    a = (torch.rand(8, 10) * 2 - 1).requires_grad_(True)
    loss = MaskedVAELoss(vae, seed=0)
    out = loss(TensorDict(action_tea=a, batch_size=[8]))
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    assert a.grad is None
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in vae.parameters())
    assert {id(p) for p in loss.parameters()} == {id(p) for p in vae.parameters()}


def test_seeded_sampling_is_reproducible():
    torch.manual_seed(0)
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    td = TensorDict(action_tea=torch.rand(8, 10) * 2 - 1, batch_size=[8])
    o1, o2, o3 = (MaskedVAELoss(vae, seed=s)(td) for s in (7, 7, 8))
    torch.testing.assert_close(o1["vae_mask"], o2["vae_mask"])
    torch.testing.assert_close(o1["vae_self"], o2["vae_self"])
    assert not torch.allclose(o1["vae_self"], o3["vae_self"])


def test_keys_nt_batches_and_padding():
    torch.manual_seed(0)
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    a = torch.rand(3, 4, 10) * 2 - 1
    loss = MaskedVAELoss(vae, sample_latent=False, mask_ratio=0.0)  # deterministic
    out_nt = loss(TensorDict(action_tea=a, batch_size=[3, 4]))
    out_flat = loss(TensorDict(action_tea=a.reshape(12, 10), batch_size=[12]))
    for k in out_nt.keys():
        torch.testing.assert_close(out_nt[k], out_flat[k])
    loss.vae.fit_bounds(a)  # (fitting is order-sensitive: fit once, on the valid data)
    padded = torch.cat([a, 50.0 * torch.ones(3, 2, 10)], 1)
    valid = torch.zeros(3, 6, dtype=torch.bool)
    valid[:, :4] = True
    loss.set_keys(action_tea=("teacher", "action"), mask="valid")
    out_pad = loss(TensorDict({("teacher", "action"): padded, "valid": valid}, batch_size=[3, 6]))
    for k in out_nt.keys():
        torch.testing.assert_close(out_pad[k], out_nt[k])


def test_auto_fit_bounds_on_first_valid_batch():
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    loss = MaskedVAELoss(vae, seed=0)
    a = torch.rand(4, 6, 10) - 0.5  # in [-0.5, 0.5)
    a[:, 4:] = 50.0  # padding, masked out below: must not widen the bounds
    valid = torch.ones(4, 6, dtype=torch.bool)
    valid[:, 4:] = False
    # the default mask key is torchrl's valid-step mask (docs/keys.md)
    loss(TensorDict({"action_tea": a, ("collector", "mask"): valid}, batch_size=[4, 6]))
    assert vae.bounds_fitted
    data = a[:, :4].reshape(-1, 10)
    lo, hi = data.min(0).values, data.max(0).values
    torch.testing.assert_close(vae.action_low, lo - 0.1 * (hi - lo))
    torch.testing.assert_close(vae.action_high, hi + 0.1 * (hi - lo))
    before = vae.action_high.clone()
    loss(TensorDict(action_tea=3 * torch.ones(2, 10), batch_size=[2]))  # never refits
    assert torch.equal(vae.action_high, before)
    off = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    MaskedVAELoss(off, auto_fit_bounds=False)(TensorDict(action_tea=data, batch_size=[16]))
    assert not off.bounds_fitted and torch.equal(off.action_high, torch.full((10,), 5.0))


def test_bad_arguments():
    with pytest.raises(ValueError, match="masking ratio"):
        MaskedVAELoss(mask_ratio=1.0)
    with pytest.raises(ValueError, match="kl_reduction"):
        MaskedVAELoss(kl_reduction="max")
    with pytest.raises(ValueError, match="recon_reduction"):
        MaskedVAELoss(recon_reduction="max")
    with pytest.raises(TypeError, match="MaskedVAE"):
        MaskedVAELoss(nn.Linear(2, 2))
    loss = MaskedVAELoss(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    with pytest.raises(ValueError, match="action_dim=10"):
        loss(TensorDict(action_tea=torch.zeros(4, 12), batch_size=[4]))


def test_vae_trains_on_correlated_actions():
    # synthetic "gaits": 10 joint actions driven by 2 phases, so joints are strongly coupled
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny matmuls: threads only add contention
    try:
        torch.manual_seed(0)
        mix = torch.randn(4, 10)

        def batch(n):
            phase = torch.rand(n, 2) * 2 * math.pi
            feats = torch.cat([phase.sin(), phase.cos()], -1)
            return TensorDict(action_tea=torch.tanh(0.6 * feats @ mix), batch_size=[n])

        vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=16, hidden_dim=64))
        loss = MaskedVAELoss(vae, seed=0)
        opt = torch.optim.Adam(loss.parameters(), lr=3e-3)
        fixed = batch(512)
        eval_loss = MaskedVAELoss(vae, sample_latent=False, seed=1)

        def recon():
            with torch.no_grad():
                o = eval_loss(fixed)
            return o["vae_self"].item(), o["vae_mask"].item()

        loss(batch(128))  # the first call fits the VAE's bounds to the teacher's actions
        assert vae.bounds_fitted
        self0, mask0 = recon()
        totals = []
        for _ in range(200):
            out = loss(batch(128))
            total = sum(v for k, v in out.items() if k.startswith("loss_"))
            opt.zero_grad()
            total.backward()
            opt.step()
            totals.append(total.item())
        self1, mask1 = recon()
        kl = out["vae_kl"].item()
    finally:
        torch.set_num_threads(threads)
    # measured: total x0.73, self x0.57, mask x0.60, vae_kl 0.08 after 200 steps
    assert sum(totals[-10:]) / 10 < 0.85 * sum(totals[:10]) / 10
    assert self1 < 0.7 * self0 and mask1 < 0.75 * mask0
    assert kl > 0.03  # the latent carries information (no posterior collapse)
