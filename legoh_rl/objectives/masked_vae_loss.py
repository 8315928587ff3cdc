"""Masked-VAE reconstruction loss L_rec of LEGO-H (paper Eqs. 2-5, "Hierarchical Latent Matching")."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import NestedKey, TensorDict, TensorDictBase
from torch import Tensor
from torchrl.objectives import LossModule

from legoh_rl.modules.masked_vae import MaskedVAE, MaskedVAEConfig, num_masked_joints
from legoh_rl.objectives._common import (
    VALID_MASK_KEY,
    SeededGenerators,
    check_reduction,
    check_weight,
    get_entry,
    get_padding_mask,
    reduce_samples,
)

__all__ = ["MaskedVAELoss"]


class MaskedVAELoss(LossModule):
    r"""Trains the masked VAE on teacher actions (Eqs. 2-5)::

        L_rec  = w4 L_KL + w5 L_self + w6 L_mask
        L_KL   = KL(q(z | a_tea) || N(0, I))
        L_self = SmoothL1(Dec(Enc(a_tea)),   a_tea)
        L_mask = SmoothL1(Dec(Enc(a_tmask)), a_tea)

    ``a_tea`` is read at ``action_tea`` (``(*B, A)``, ``*B`` = ``[N]`` or ``[N, T]``) and
    detached. ``a_tmask`` masks exactly ``num_masked_joints(mask_ratio, A)`` random joints per
    sample with the VAE's fill value (the mid-point of its bounds, 0.5 in unit space) using this
    loss's seeded generator. ``Enc`` draws ``z = mu + sigma * eps`` (reparameterisation, same
    generator) when ``sample_latent`` is True (default, the VAE formulation), else uses ``mu``.

    Reconstructions are compared in the VAE's unit space, where the paper's decoder output lives
    (it ends in a sigmoid): ``SmoothL1(sigmoid_out, to_unit(a_tea))``. Together with bounds
    fitted to the teacher's actions this makes the loss independent of the action amplitude.
    Bounds: with ``auto_fit_bounds`` (default) the first call whose VAE has not been fitted yet
    runs ``vae.fit_bounds`` on that batch's valid teacher actions (margin ``fit_margin``); the
    bounds are buffers and stay fixed afterwards (also across checkpoint reloads).

    Per sample, SmoothL1 is **summed** over the ``A`` joints (``recon_reduction="sum"``,
    default; ``"mean"`` averages) and the closed-form Gaussian KL
    ``0.5 * (mu^2 + exp(logvar) - 1 - logvar)`` is **averaged** over the latent dimension
    (``kl_reduction="mean"``, default; ``"sum"`` is Kingma & Welling's exact KL). The paper
    gives the weights (w4 = w5 = w6 = 1) but not the reductions; these defaults were chosen by
    measurement (docs/objectives.md): on coupled 10-joint actions, the three other
    combinations collapse the posterior to the prior (decoding error stays at the data
    variance, ``vae_kl`` -> 0), which leaves HLM a latent with no information. Watch the
    ``vae_kl`` diagnostic: near 0 means collapse. Then each term is averaged over the valid
    samples (padding mask key ``mask``, default ``("collector", "mask")``, bool ``(*B,)`` or
    ``(*B, 1)``; missing = all valid).

    The loss owns the VAE (``self.vae``, registered, trainable): optimise
    ``loss.parameters()`` (or ``loss.vae.parameters()``). :class:`~legoh_rl.objectives.HLMLoss`
    built from this loss (``HLMLoss(vae_loss)``) reads the same VAE, frozen, and therefore always
    uses its current weights.

    Args:
        vae: a :class:`~legoh_rl.modules.masked_vae.MaskedVAE`, a config to build one, or
            ``None`` for the default config.

    Keyword Args:
        w4, w5, w6: weights of the KL, self-reconstruction and masked-reconstruction terms
            (paper: 1, 1, 1).
        mask_ratio: fraction of joints masked in ``a_tmask``, in ``[0, 1)`` (default 0.3:
            3 of 10 joints).
        sample_latent: decode a reparameterised sample (True) or the mean (False).
        kl_reduction: ``"mean"`` (default) or ``"sum"`` of the KL over the latent dimension.
        recon_reduction: ``"sum"`` (default) or ``"mean"`` of SmoothL1 over the joints.
        auto_fit_bounds: fit the VAE's bounds to the first batch if not fitted yet (True).
        fit_margin: margin of that fit, a fraction of each joint's range (0.1).
        smooth_l1_beta: SmoothL1 transition point (default 1.0).
        seed: seed of the masking / sampling generator (``None``: drawn from torch's global RNG).
        reduction: ``"mean"``, ``"sum"`` or ``"none"`` over samples.

    Input keys: ``action_tea`` -> ``"action_tea"``, ``mask`` -> ``("collector", "mask")``
    (:data:`~legoh_rl.objectives.VALID_MASK_KEY`).

    Returns:
        A TensorDict with ``loss_vae_kl``, ``loss_vae_self``, ``loss_vae_mask`` (weighted) and
        the unweighted, detached diagnostics ``vae_kl``, ``vae_self``, ``vae_mask``.
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys, see the class docstring."""

        action_tea: NestedKey = "action_tea"
        mask: NestedKey = VALID_MASK_KEY

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = [
        "loss_vae_kl",
        "loss_vae_self",
        "loss_vae_mask",
        "vae_kl",
        "vae_self",
        "vae_mask",
    ]

    def __init__(
        self,
        vae: MaskedVAE | MaskedVAEConfig | None = None,
        *,
        w4: float = 1.0,
        w5: float = 1.0,
        w6: float = 1.0,
        mask_ratio: float = 0.3,
        sample_latent: bool = True,
        kl_reduction: str = "mean",
        recon_reduction: str = "sum",
        auto_fit_bounds: bool = True,
        fit_margin: float = 0.1,
        smooth_l1_beta: float = 1.0,
        seed: int | None = None,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        if not isinstance(vae, MaskedVAE):
            if vae is not None and not isinstance(vae, MaskedVAEConfig):
                raise TypeError(
                    f"vae must be a MaskedVAE, a MaskedVAEConfig or None, got {type(vae).__name__}"
                )
            vae = MaskedVAE(vae)
        self.vae = vae
        self.w4 = check_weight("w4", w4)
        self.w5 = check_weight("w5", w5)
        self.w6 = check_weight("w6", w6)
        num_masked_joints(mask_ratio, vae.action_dim)  # validates the ratio
        self.mask_ratio = float(mask_ratio)
        self.sample_latent = bool(sample_latent)
        if kl_reduction not in ("mean", "sum"):
            raise ValueError(f"kl_reduction must be 'mean' or 'sum', got {kl_reduction!r}")
        self.kl_reduction = kl_reduction
        if recon_reduction not in ("mean", "sum"):
            raise ValueError(f"recon_reduction must be 'mean' or 'sum', got {recon_reduction!r}")
        self.recon_reduction = recon_reduction
        self.auto_fit_bounds = bool(auto_fit_bounds)
        if not fit_margin >= 0:
            raise ValueError(f"fit_margin must be >= 0, got {fit_margin!r}")
        self.fit_margin = float(fit_margin)
        if not smooth_l1_beta > 0:
            raise ValueError(f"smooth_l1_beta must be > 0, got {smooth_l1_beta!r}")
        self.smooth_l1_beta = float(smooth_l1_beta)
        self.generators = SeededGenerators(seed)
        self.reduction = check_reduction(reduction)

    @property
    def functional(self) -> bool:
        return False

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator in this loss: nothing to forward (LossModule hook)."""

    @property
    def in_keys(self) -> list[NestedKey]:
        return [self.tensor_keys.action_tea, self.tensor_keys.mask]

    def _reconstruct(self, a: Tensor, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        """Encode actions ``a``; return (unit-space reconstruction, mu, logvar)."""
        mu, logvar = self.vae.encode(a)
        z = self.vae.reparameterize(mu, logvar, gen) if self.sample_latent else mu
        return self.vae.decoder(z), mu, logvar

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Compute L_rec on a ``[N]`` or ``[N, T]`` batch; see the class docstring."""
        a_tea = get_entry(tensordict, self.tensor_keys.action_tea, "MaskedVAELoss").detach()
        self.vae.check_actions(a_tea, "teacher actions")
        mask = get_padding_mask(tensordict, self.tensor_keys.mask, a_tea.shape[:-1])
        if self.auto_fit_bounds and not bool(self.vae.bounds_fitted):
            valid = a_tea if mask is None else a_tea[mask]
            if valid.numel() > 0:
                self.vae.fit_bounds(valid, margin=self.fit_margin)
        gen = self.generators.get(a_tea.device)
        # masks are drawn first, then the latent noise (fixed order: reproducible with a seed)
        a_tmask, _ = self.vae.mask_joints(a_tea, self.mask_ratio, gen)
        u_rec, mu, logvar = self._reconstruct(a_tea, gen)
        u_rec_mask, _, _ = self._reconstruct(a_tmask, gen)
        u_tea = self.vae.to_unit(a_tea)

        kl = 0.5 * (mu.pow(2) + logvar.exp() - 1.0 - logvar)
        kl = kl.mean(-1) if self.kl_reduction == "mean" else kl.sum(-1)
        self_rec = F.smooth_l1_loss(u_rec, u_tea, reduction="none", beta=self.smooth_l1_beta)
        mask_rec = F.smooth_l1_loss(
            u_rec_mask, u_tea, reduction="none", beta=self.smooth_l1_beta
        )
        if self.recon_reduction == "sum":
            self_rec, mask_rec = self_rec.sum(-1), mask_rec.sum(-1)
        else:
            self_rec, mask_rec = self_rec.mean(-1), mask_rec.mean(-1)
        per_sample = {"kl": kl, "self": self_rec, "mask": mask_rec}
        out = {}
        for name, weight in (("kl", self.w4), ("self", self.w5), ("mask", self.w6)):
            value = reduce_samples(per_sample[name], mask, self.reduction)
            out[f"loss_vae_{name}"] = weight * value
            out[f"vae_{name}"] = value.detach()
        return TensorDict(out, batch_size=[])

    def extra_repr(self) -> str:
        return (
            f"w4={self.w4}, w5={self.w5}, w6={self.w6}, mask_ratio={self.mask_ratio}, "
            f"sample_latent={self.sample_latent}, kl_reduction={self.kl_reduction!r}, "
            f"recon_reduction={self.recon_reduction!r}"
        )
