"""Masked VAE (HLM feature space): unit mapping, joint masking, architecture, TensorDict wrapper."""

import math

import pytest
import torch
from tensordict import TensorDict

from legoh_rl.modules.masked_vae import (
    MaskedVAE,
    MaskedVAEConfig,
    make_masked_vae_module,
    mask_joints,
    num_masked_joints,
    sincos_joint_embedding,
)


def small_cfg(**kw):
    base = dict(action_dim=10, latent_dim=4, hidden_dim=32, num_blocks=2, joint_embed_dim=4)
    base.update(kw)
    return MaskedVAEConfig(**base)


def test_unit_round_trip_is_lossless_within_bounds():
    low = [-1.0, -2.0, -0.5, -1.2, -3.0]
    high = [1.0, 0.5, 2.0, 1.2, 3.0]
    vae = MaskedVAE(small_cfg(action_dim=5, action_low=low, action_high=high))
    g = torch.Generator().manual_seed(0)
    lo, hi = torch.tensor(low), torch.tensor(high)
    a = lo + (hi - lo) * torch.rand(64, 7, 5, generator=g)
    u = vae.to_unit(a)
    assert u.min() >= 0 and u.max() <= 1
    torch.testing.assert_close(vae.from_unit(u), a, rtol=0, atol=1e-6)
    # the bounds and the mid-point map to 0, 1 and 0.5
    torch.testing.assert_close(vae.to_unit(lo), torch.zeros(5))
    torch.testing.assert_close(vae.to_unit(hi), torch.ones(5))
    torch.testing.assert_close(vae.to_unit((lo + hi) / 2), torch.full((5,), 0.5))
    # and the inverse is exact on [0, 1]
    uu = torch.rand(10, 5, generator=g)
    torch.testing.assert_close(vae.to_unit(vae.from_unit(uu)), uu, rtol=0, atol=1e-6)


def test_unit_mapping_default_bounds_and_clamp():
    vae = MaskedVAE(small_cfg(action_dim=2))
    # documented default: the env's action clip, +-5
    torch.testing.assert_close(vae.action_low, torch.full((2,), -5.0))
    torch.testing.assert_close(vae.action_high, torch.full((2,), 5.0))
    assert not vae.bounds_fitted
    u = vae.to_unit(torch.tensor([[0.0, 2.5], [6.0, -9.0]]))
    torch.testing.assert_close(u, torch.tensor([[0.5, 0.75], [1.0, 0.0]]))
    torch.testing.assert_close(vae.fill_value, torch.zeros(2))


def test_fit_bounds():
    vae = MaskedVAE(small_cfg(action_dim=3))
    a = torch.tensor([[0.0, -1.0, 0.3], [1.0, 3.0, 0.3], [0.5, 1.0, 0.3]])
    low, high = vae.fit_bounds(a, margin=0.1, min_width=0.2)
    # joint 0: [0, 1] +- 0.1; joint 1: [-1, 3] +- 0.4; joint 2 is constant: 0.3 +- 0.1
    torch.testing.assert_close(low, torch.tensor([-0.1, -1.4, 0.2]))
    torch.testing.assert_close(high, torch.tensor([1.1, 3.4, 0.4]))
    torch.testing.assert_close(vae.action_low, low)
    assert vae.bounds_fitted and "bounds_fitted" in vae.state_dict()
    # the round trip stays exact with the fitted bounds
    torch.testing.assert_close(vae.from_unit(vae.to_unit(a)), a)
    fresh = MaskedVAE(small_cfg(action_dim=3))
    fresh.load_state_dict(vae.state_dict())
    assert fresh.bounds_fitted and torch.equal(fresh.action_high, vae.action_high)
    with pytest.raises(ValueError, match="NaN or inf"):
        vae.fit_bounds(torch.tensor([[float("nan"), 0.0, 0.0]]))
    with pytest.raises(ValueError, match="margin"):
        vae.fit_bounds(a, margin=-1.0)


def test_num_masked_joints_rounding_and_errors():
    assert num_masked_joints(0.0, 10) == 0
    assert num_masked_joints(0.3, 10) == 3
    assert num_masked_joints(0.25, 10) == 3  # round half up
    assert num_masked_joints(0.24, 10) == 2
    assert num_masked_joints(0.5, 12) == 6
    assert num_masked_joints(0.97, 10) == 9  # never every joint
    for bad in (-0.1, 1.0, 1.5, float("nan"), "0.3"):
        with pytest.raises(ValueError, match="masking ratio"):
            num_masked_joints(bad, 10)


@pytest.mark.parametrize("ratio,k", [(0.1, 1), (0.3, 3), (0.5, 5), (0.8, 8)])
def test_mask_joints_masks_exactly_k_per_sample(ratio, k):
    g = torch.Generator().manual_seed(1)
    a = torch.randn(32, 6, 10, generator=g) + 3.0  # no entry equals the fill value
    a_masked, mask = mask_joints(a, ratio, generator=g, fill_value=-7.0)
    assert mask.dtype == torch.bool and mask.shape == a.shape
    assert (mask.sum(-1) == k).all()
    assert (a_masked[mask] == -7.0).all()
    torch.testing.assert_close(a_masked[~mask], a[~mask])
    # the chosen joints vary between samples
    assert len({tuple(m.tolist()) for m in mask.reshape(-1, 10)}) >= 10


def test_mask_joints_reproducible_and_gradient_reaches_unmasked():
    a = torch.randn(8, 10, requires_grad=True)
    m1 = mask_joints(a, 0.3, torch.Generator().manual_seed(5))[1]
    m2 = mask_joints(a, 0.3, torch.Generator().manual_seed(5))[1]
    m3 = mask_joints(a, 0.3, torch.Generator().manual_seed(6))[1]
    assert torch.equal(m1, m2) and not torch.equal(m1, m3)
    a_masked, mask = mask_joints(a, 0.3, torch.Generator().manual_seed(5))
    a_masked.sum().backward()
    torch.testing.assert_close(a.grad, (~mask).float())


def test_mask_joints_ratio_zero_and_errors():
    a = torch.randn(4, 10)
    a_masked, mask = mask_joints(a, 0.0)
    assert not mask.any() and torch.equal(a_masked, a)
    with pytest.raises(ValueError, match="masking ratio"):
        mask_joints(a, 1.0)
    with pytest.raises(ValueError, match="fill_value"):
        mask_joints(a, 0.3, fill_value=torch.zeros(3))


def test_vae_mask_joints_uses_midpoint_fill():
    vae = MaskedVAE(small_cfg(action_dim=3, action_low=[0.0, -1.0, -4.0], action_high=[2.0, 1.0, 0.0]))
    a = torch.full((50, 3), 0.7)
    a_masked, mask = vae.mask_joints(a, 0.34, torch.Generator().manual_seed(0))
    assert (mask.sum(-1) == 1).all()
    fill = torch.tensor([1.0, 0.0, -2.0]).expand(50, 3)
    torch.testing.assert_close(a_masked[mask], fill[mask])
    torch.testing.assert_close(vae.to_unit(a_masked)[mask], torch.full((50,), 0.5))


def test_sincos_joint_embedding():
    pe = sincos_joint_embedding(10, 6)
    assert pe.shape == (10, 6)
    torch.testing.assert_close(pe[0], torch.tensor([0.0, 1.0, 0.0, 1.0, 0.0, 1.0]))
    torch.testing.assert_close(pe[3, 0], torch.tensor(math.sin(3.0)))
    torch.testing.assert_close(pe[3, 3], torch.tensor(math.cos(3.0 / 10000 ** (2 / 6))))
    # every joint gets a distinct code
    assert torch.cdist(pe, pe).add(torch.eye(10)).min() > 1e-3


def test_vae_shapes_bounds_and_modes():
    torch.manual_seed(0)
    vae = MaskedVAE(small_cfg())
    for batch in ((5,), (3, 4)):
        a = torch.rand(*batch, 10) * 2 - 1
        a_rec, mu, logvar = vae(a)
        assert a_rec.shape == a.shape and mu.shape == (*batch, 4) and logvar.shape == (*batch, 4)
        assert (a_rec > -5.0).all() and (a_rec < 5.0).all()
        torch.testing.assert_close(vae.latent(a), mu)
        torch.testing.assert_close(vae.decode(mu).shape, a.shape)
    a = torch.rand(6, 10)
    vae.eval()
    torch.testing.assert_close(vae(a)[0], vae(a)[0])  # mean decoding
    torch.testing.assert_close(vae(a)[0], vae.decode(vae.latent(a)))
    vae.train()
    s1 = vae(a, generator=torch.Generator().manual_seed(3))[0]
    s2 = vae(a, generator=torch.Generator().manual_seed(3))[0]
    s3 = vae(a, generator=torch.Generator().manual_seed(4))[0]
    torch.testing.assert_close(s1, s2)
    assert not torch.allclose(s1, s3)
    # the joint embedding is fixed, not trained
    names = {n for n, _ in vae.named_parameters()}
    assert not any("joint_pe" in n for n in names)
    assert "encoder.joint_pe" in dict(vae.named_buffers())
    assert len(vae.encoder.blocks) == 2 and len(vae.decoder.blocks) == 2


def test_joint_identity_matters():
    # the shared tokenizer sees the joint index only through the sin-cos code: swapping two
    # joints' values changes the latent
    torch.manual_seed(0)
    vae = MaskedVAE(small_cfg())
    a = torch.rand(1, 10) * 2 - 1
    swapped = a[:, [1, 0, *range(2, 10)]]
    assert not torch.allclose(vae.latent(a), vae.latent(swapped))


def test_config_and_shape_errors():
    with pytest.raises(ValueError, match="action_dim"):
        MaskedVAEConfig(action_dim=0)
    with pytest.raises(ValueError, match="joint_embed_dim must be even"):
        MaskedVAEConfig(joint_embed_dim=5)
    with pytest.raises(ValueError, match="action_high must exceed action_low"):
        MaskedVAEConfig(action_dim=2, action_low=[0.0, 1.0], action_high=[1.0, 1.0])
    with pytest.raises(ValueError, match="action_low must be a scalar or have 10"):
        MaskedVAEConfig(action_low=[-1.0, -1.0])
    vae = MaskedVAE(small_cfg())
    with pytest.raises(ValueError, match=r"\(\.\.\., 10\).*got shape \(4, 12\)"):
        vae.encode(torch.zeros(4, 12))
    with pytest.raises(ValueError, match="latents of shape"):
        vae.decode(torch.zeros(4, 5))


def test_tensordict_module_builder():
    torch.manual_seed(0)
    mod = make_masked_vae_module(small_cfg())
    td = TensorDict(action_tea=torch.rand(3, 5, 10), batch_size=[3, 5])
    mod.eval()
    out = mod(td)
    assert out["vae_action_rec"].shape == (3, 5, 10) and out["vae_mu"].shape == (3, 5, 4)
    vae = mod.module
    shared = make_masked_vae_module(vae, in_key="loc", out_keys=["rec", "mu", "lv"])
    assert shared.module is vae
    td2 = shared(TensorDict(loc=td["action_tea"], batch_size=[3, 5]))
    torch.testing.assert_close(td2["mu"], out["vae_mu"])
    with pytest.raises(ValueError, match="3 out_keys"):
        make_masked_vae_module(vae, out_keys=["a", "b"])
