"""HLMLoss (paper Eqs. 6-9): hand-computed values, frozen shared VAE, keys, [N, T], padding."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from legoh_rl.modules.masked_vae import MaskedVAE, MaskedVAEConfig, mask_joints
from legoh_rl.objectives import DAggerLoss, HLMLoss, MaskedVAELoss


class IdentityEncoder(nn.Module):
    """mu = 2u - 1 = the action itself for bounds +-1 (a trainable Linear set to known values)."""

    def __init__(self):
        super().__init__()
        self.lin = nn.Linear(2, 2)
        with torch.no_grad():
            self.lin.weight.copy_(2.0 * torch.eye(2))
            self.lin.bias.fill_(-1.0)

    def forward(self, u):
        mu = self.lin(u)
        return mu, torch.zeros_like(mu)


def identity_vae():
    vae = MaskedVAE(
        MaskedVAEConfig(action_dim=2, latent_dim=2, hidden_dim=4, action_low=-1.0, action_high=1.0)
    )
    vae.encoder = IdentityEncoder()
    return vae


A_TEA = torch.tensor([[1.0, 0.0], [0.6, 0.8]])
A_UNI = torch.tensor([[0.6, 0.8], [0.0, 0.5]])
# by hand: cos(tea, uni) = [0.6, (0.6*0 + 0.8*0.5) / (1 * 0.5) = 0.8] -> L_ts = [0.4, 0.2]
TS = [0.4, 0.2]
# masking one student joint (fill 0); L_trip = 0.85 (1 - cos(tea, um)) + 0.15 (1 - cos(uni, um))
TRIP = {
    (0, 0): 0.85 * (1 - 0.0) + 0.15 * (1 - 0.8),  # um = (0, 0.8)
    (0, 1): 0.85 * (1 - 1.0) + 0.15 * (1 - 0.6),  # um = (0.6, 0)
    (1, 0): 0.85 * (1 - 0.8) + 0.15 * (1 - 1.0),  # um = (0, 0.5)
    (1, 1): 0.85 * (1 - 0.0) + 0.15 * (1 - 0.0),  # um = (0, 0): cosine 0 by the eps guard
}


def batch(a_uni=A_UNI):
    return TensorDict(action_tea=A_TEA, loc=a_uni, batch_size=[2])


def test_matches_hand_computation_without_masking():
    out = HLMLoss(identity_vae(), mask_ratio=0.0)(batch())
    torch.testing.assert_close(out["hlm_ts"], torch.tensor(0.3))
    torch.testing.assert_close(out["loss_hlm_ts"], torch.tensor(100.0 * 0.3))
    # no joint masked: a_umask = a_uni, so L_trip = 0.85 L_ts
    torch.testing.assert_close(out["hlm_trip"], torch.tensor(0.85 * 0.3))
    torch.testing.assert_close(out["loss_hlm_trip"], torch.tensor(2.0 * 0.85 * 0.3))
    torch.testing.assert_close(out["cos_tea_uni"], torch.tensor(0.7))


def test_matches_hand_computation_with_masking():
    loss = HLMLoss(identity_vae(), mask_ratio=0.5, seed=11, w7=3.0, w8=5.0)
    out = loss(batch())
    _, jm = mask_joints(A_UNI, 0.5, torch.Generator().manual_seed(11))  # the loss's draw
    trip = [TRIP[(i, int(jm[i].nonzero()))] for i in range(2)]
    torch.testing.assert_close(out["loss_hlm_ts"], torch.tensor(3.0 * sum(TS) / 2))
    torch.testing.assert_close(out["loss_hlm_trip"], torch.tensor(5.0 * sum(trip) / 2))
    per = HLMLoss(identity_vae(), mask_ratio=0.5, seed=11, reduction="none")(batch())
    torch.testing.assert_close(per["hlm_ts"], torch.tensor(TS))
    torch.testing.assert_close(per["hlm_trip"], torch.tensor(trip))


def test_gradient_reaches_student_never_the_vae():
    vae_loss = MaskedVAELoss(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16), seed=0)
    hlm = HLMLoss(vae_loss, seed=0)
    assert hlm.vae is vae_loss.vae
    assert list(hlm.parameters()) == [] and len(hlm.state_dict()) == 0
    a_tea = (torch.rand(6, 10) * 2 - 1).requires_grad_(True)
    a_uni = (torch.rand(6, 10) * 2 - 1).requires_grad_(True)
    out = hlm(TensorDict(action_tea=a_tea, loc=a_uni, batch_size=[6]))
    (out["loss_hlm_ts"] + out["loss_hlm_trip"]).backward()
    assert a_uni.grad is not None and a_uni.grad.abs().sum() > 0
    assert a_tea.grad is None
    assert all(p.grad is None for p in vae_loss.vae.parameters())
    assert all(p.requires_grad for p in vae_loss.vae.parameters())  # flags untouched
    # the linear stub's weights are not trained either
    stub = identity_vae()
    a = A_UNI.clone().requires_grad_(True)
    HLMLoss(stub, mask_ratio=0.5, seed=0)(batch(a))["loss_hlm_ts"].backward()
    assert stub.encoder.lin.weight.grad is None and a.grad.abs().sum() > 0


def test_student_improves_and_follows_vae_updates():
    torch.manual_seed(0)
    vae_loss = MaskedVAELoss(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16), seed=0)
    hlm = HLMLoss(vae_loss, seed=0)
    td = TensorDict(
        action_tea=torch.rand(16, 10) * 2 - 1,
        loc=(torch.rand(16, 10) * 2 - 1).requires_grad_(True),
        batch_size=[16],
    )
    before = hlm(td)["hlm_ts"]
    # one VAE step (what MaskedVAELoss does during distillation) changes what HLM sees
    opt_vae = torch.optim.SGD(vae_loss.parameters(), lr=0.5)
    out = vae_loss(td)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    opt_vae.step()
    after_vae = hlm(td)["hlm_ts"]
    assert not torch.allclose(before, after_vae)
    # a gradient step on the student action reduces L_ts
    opt = torch.optim.SGD([td["loc"]], lr=0.1)
    out = hlm(td)
    out["loss_hlm_ts"].backward()
    opt.step()
    assert hlm(td)["hlm_ts"] < after_vae


def test_set_keys_nt_batches_and_padding():
    torch.manual_seed(0)
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    n, t = 3, 4
    a_tea, a_uni = torch.rand(n, t, 10) * 2 - 1, torch.rand(n, t, 10) * 2 - 1
    loss = HLMLoss(vae, mask_ratio=0.0)  # no randomness: compare layouts exactly
    out_nt = loss(TensorDict(action_tea=a_tea, loc=a_uni, batch_size=[n, t]))
    out_flat = loss(
        TensorDict(action_tea=a_tea.reshape(-1, 10), loc=a_uni.reshape(-1, 10), batch_size=[n * t])
    )
    for k in out_nt.keys():
        torch.testing.assert_close(out_nt[k], out_flat[k])
    pad = torch.full((n, 2, 10), 0.9)
    uni_pad = torch.cat([a_uni, -pad], 1).requires_grad_(True)
    td = TensorDict(
        {
            ("teacher", "a"): torch.cat([a_tea, pad], 1),
            ("student", "loc"): uni_pad,
            ("collector", "mask"): torch.arange(t + 2).expand(n, t + 2).lt(t).unsqueeze(-1),
        },
        batch_size=[n, t + 2],
    )
    loss.set_keys(action_tea=("teacher", "a"), action_uni=("student", "loc"), mask=("collector", "mask"))
    out_pad = loss(td)
    for k in out_nt.keys():
        torch.testing.assert_close(out_pad[k], out_nt[k])
    out_pad["loss_hlm_ts"].backward()
    assert (uni_pad.grad[:, t:] == 0).all() and uni_pad.grad[:, :t].abs().sum() > 0


def test_student_network_option():
    torch.manual_seed(0)
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    student = TensorDictModule(nn.Linear(5, 10), in_keys=["obs"], out_keys=["loc"])
    td = TensorDict(obs=torch.randn(4, 5), action_tea=torch.rand(4, 10), loc=torch.zeros(4, 10),
                    batch_size=[4])
    out = HLMLoss(vae, student, seed=0)(td)
    ref = HLMLoss(vae, seed=0)(student(td.clone()))
    torch.testing.assert_close(out["loss_hlm_ts"], ref["loss_hlm_ts"])
    assert torch.equal(td["loc"], torch.zeros(4, 10))
    out["loss_hlm_ts"].backward()
    assert student.module.weight.grad.abs().sum() > 0


def test_bad_arguments():
    vae = MaskedVAE(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16))
    with pytest.raises(ValueError, match="masking ratio"):
        HLMLoss(vae, mask_ratio=-0.2)
    with pytest.raises(TypeError, match="MaskedVAE or a MaskedVAELoss"):
        HLMLoss(nn.Linear(3, 3))
    with pytest.raises(ValueError, match="c_mt must be a finite number >= 0"):
        HLMLoss(vae, c_mt=float("nan"))
    with pytest.raises(ValueError, match="same shape"):
        HLMLoss(vae)(TensorDict(action_tea=torch.zeros(4, 10), loc=torch.zeros(4, 12), batch_size=[4]))
    with pytest.raises(ValueError, match="action_dim=10"):
        HLMLoss(vae)(TensorDict(action_tea=torch.zeros(4, 12), loc=torch.zeros(4, 12), batch_size=[4]))


def test_composed_losses_train_vae_only_through_lrec():
    torch.manual_seed(0)
    vae_loss = MaskedVAELoss(MaskedVAEConfig(action_dim=10, latent_dim=4, hidden_dim=16), seed=3)
    hlm = HLMLoss(vae_loss, seed=4)
    student = TensorDictModule(nn.Linear(5, 10), in_keys=["obs"], out_keys=["loc"])
    td = TensorDict(obs=torch.randn(8, 5), action_tea=torch.rand(8, 10) * 2 - 1, batch_size=[8])
    mb = student(td.clone(False))
    outs = [DAggerLoss(w1=0.0, w2=0.0)(mb), hlm(mb), vae_loss(mb)]
    total = sum(v for o in outs for k, v in o.items() if k.startswith("loss_"))
    total.backward()
    vae_grads = [p.grad.clone() for p in vae_loss.vae.parameters()]
    assert student.module.weight.grad.abs().sum() > 0
    # the VAE's gradient is exactly L_rec's (same seed -> same masks and noise)
    vae_loss.zero_grad()
    vae_loss.generators.reset()
    out = vae_loss(mb)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    for g, p in zip(vae_grads, vae_loss.vae.parameters(), strict=True):
        torch.testing.assert_close(g, p.grad)
