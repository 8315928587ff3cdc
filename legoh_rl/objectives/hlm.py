"""Hierarchical Latent Matching loss L_hie of LEGO-H (paper Eqs. 6-9)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.objectives import LossModule

from legoh_rl.modules.masked_vae import MaskedVAE, num_masked_joints
from legoh_rl.objectives._common import (
    VALID_MASK_KEY,
    SeededGenerators,
    check_reduction,
    check_same_shape,
    check_weight,
    get_entry,
    get_padding_mask,
    reduce_samples,
    run_student,
)
from legoh_rl.objectives.masked_vae_loss import MaskedVAELoss

__all__ = ["HLMLoss", "cosine_similarity"]


def cosine_similarity(x: Tensor, y: Tensor, eps: float = 1e-8) -> Tensor:
    """``x . y / (max(||x||, eps) * max(||y||, eps))`` over the last dimension: ``(..., Z) -> (...)``."""
    nx = x.norm(dim=-1).clamp_min(eps)
    ny = y.norm(dim=-1).clamp_min(eps)
    return (x * y).sum(-1) / (nx * ny)


class HLMLoss(LossModule):
    r"""Hierarchical Latent Matching between teacher and student actions (Eqs. 6-9)::

        L_ts   = 1 - cos(Enc(a_tea), Enc(a_uni))
        L_trip = c_mt (1 - cos(Enc(a_tea), Enc(a_umask))) + c_ms (1 - cos(Enc(a_uni), Enc(a_umask)))
        L_hie  = w7 L_ts + w8 L_trip

    ``Enc`` is the masked VAE's encoder mean ``mu`` (``(*B, Z)``) of actions ``(*B, A)``
    (``*B`` = ``[N]`` or ``[N, T]``); ``a_umask`` masks exactly
    ``num_masked_joints(mask_ratio, A)`` random joints of the student action per sample with
    the VAE's fill value (mid-point of its bounds), drawn from this loss's seeded generator.
    Cosines are per sample; each term is averaged over the valid samples (padding mask key
    ``mask``, default ``("collector", "mask")``, bool ``(*B,)`` or ``(*B, 1)``; missing = all
    valid).

    Sharing the VAE. The VAE is trained by :class:`~legoh_rl.objectives.MaskedVAELoss`
    during distillation ("iteratively", paper Sec. HLM) and HLM must always see its current
    weights while never training it. This loss therefore keeps a plain *reference* to that VAE
    (not a registered submodule: ``HLMLoss.parameters()`` and ``state_dict()`` do not include
    it, and ``.to()`` does not move it: the owner does) and evaluates the encoder with
    ``torch.func.functional_call`` on *detached* views of its current parameters. Gradients
    therefore reach the student's action (and through it the policy), never the VAE, without
    touching ``requires_grad`` flags that ``MaskedVAELoss`` relies on. The teacher encoding is
    computed under ``no_grad``.

    Args:
        vae: the :class:`~legoh_rl.modules.masked_vae.MaskedVAE` to read, or the
            :class:`~legoh_rl.objectives.MaskedVAELoss` that owns it (its ``.vae`` is used).
        student_network: optional TensorDictModule producing the student action; when given
            it is run on every call on a shallow copy of the input (see
            :class:`~legoh_rl.objectives.DAggerLoss`). Otherwise the action is read from the
            input.

    Keyword Args:
        w7, w8: weights of L_ts and L_trip (paper: 100, 2).
        c_mt, c_ms: weights inside L_trip (paper: 0.85, 0.15).
        mask_ratio: fraction of student joints masked in ``a_umask``, in ``[0, 1)``
            (default 0.3).
        eps: lower bound on latent norms in the cosine (default 1e-8).
        seed: seed of the masking generator (``None``: drawn from torch's global RNG).
        reduction: ``"mean"``, ``"sum"`` or ``"none"`` over samples.

    Input keys: ``action_tea`` -> ``"action_tea"``, ``action_uni`` -> ``"loc"`` (the
    student's deterministic mean, so the gradient reaches the policy), ``mask`` ->
    ``("collector", "mask")`` (:data:`~legoh_rl.objectives.VALID_MASK_KEY`).

    Returns:
        A TensorDict with ``loss_hlm_ts`` (``w7 * L_ts``), ``loss_hlm_trip``
        (``w8 * L_trip``) and the unweighted, detached diagnostics ``hlm_ts``, ``hlm_trip``,
        ``cos_tea_uni`` (mean cosine between teacher and student latents).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys, see the class docstring."""

        action_tea: NestedKey = "action_tea"
        action_uni: NestedKey = "loc"
        mask: NestedKey = VALID_MASK_KEY

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_hlm_ts", "loss_hlm_trip", "hlm_ts", "hlm_trip", "cos_tea_uni"]

    def __init__(
        self,
        vae: MaskedVAE | MaskedVAELoss,
        student_network: TensorDictModuleBase | None = None,
        *,
        w7: float = 100.0,
        w8: float = 2.0,
        c_mt: float = 0.85,
        c_ms: float = 0.15,
        mask_ratio: float = 0.3,
        eps: float = 1e-8,
        seed: int | None = None,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        if isinstance(vae, MaskedVAELoss):
            vae = vae.vae
        if not isinstance(vae, MaskedVAE):
            raise TypeError(
                f"vae must be a MaskedVAE or a MaskedVAELoss, got {type(vae).__name__}"
            )
        # a reference, deliberately not registered as a submodule (see the class docstring)
        object.__setattr__(self, "_vae", vae)
        self.student_network = student_network
        self.w7 = check_weight("w7", w7)
        self.w8 = check_weight("w8", w8)
        self.c_mt = check_weight("c_mt", c_mt)
        self.c_ms = check_weight("c_ms", c_ms)
        num_masked_joints(mask_ratio, vae.action_dim)  # validates the ratio
        self.mask_ratio = float(mask_ratio)
        if not eps > 0:
            raise ValueError(f"eps must be > 0, got {eps!r}")
        self.eps = float(eps)
        self.generators = SeededGenerators(seed)
        self.reduction = check_reduction(reduction)

    @property
    def vae(self) -> MaskedVAE:
        """The shared (frozen here) masked VAE."""
        return self._vae

    @property
    def functional(self) -> bool:
        return False

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator in this loss: nothing to forward (LossModule hook)."""

    @property
    def in_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        return [k.action_tea, k.action_uni, k.mask]

    def encode_frozen(self, a: Tensor) -> Tensor:
        """``Enc(a)``: the encoder mean of actions ``(..., A)`` -> ``(..., Z)``, computed with
        detached copies of the VAE's current parameters (gradients reach ``a`` only)."""
        encoder = self.vae.encoder
        params = {name: p.detach() for name, p in encoder.named_parameters()}
        mu, _ = torch.func.functional_call(encoder, params, (self.vae.to_unit(a),))
        return mu

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Compute L_hie on a ``[N]`` or ``[N, T]`` batch; see the class docstring."""
        k = self.tensor_keys
        a_tea = get_entry(tensordict, k.action_tea, "HLMLoss (teacher action)").detach()
        student = run_student(tensordict, self.student_network)
        a_uni = get_entry(student, k.action_uni, "HLMLoss (student action)")
        check_same_shape(f"teacher {k.action_tea!r}", a_tea, f"student {k.action_uni!r}", a_uni)

        with torch.no_grad():
            e_tea = self.encode_frozen(a_tea)
        e_uni = self.encode_frozen(a_uni)
        gen = self.generators.get(a_uni.device)
        a_umask, _ = self.vae.mask_joints(a_uni, self.mask_ratio, gen)
        e_umask = self.encode_frozen(a_umask)

        cos_tu = cosine_similarity(e_tea, e_uni, self.eps)
        l_ts = 1.0 - cos_tu
        l_trip = self.c_mt * (1.0 - cosine_similarity(e_tea, e_umask, self.eps)) + self.c_ms * (
            1.0 - cosine_similarity(e_uni, e_umask, self.eps)
        )
        mask = get_padding_mask(tensordict, k.mask, l_ts.shape)
        ts = reduce_samples(l_ts, mask, self.reduction)
        trip = reduce_samples(l_trip, mask, self.reduction)
        cos_mean = reduce_samples(cos_tu.detach(), mask, "mean")
        return TensorDict(
            {
                "loss_hlm_ts": self.w7 * ts,
                "loss_hlm_trip": self.w8 * trip,
                "hlm_ts": ts.detach(),
                "hlm_trip": trip.detach(),
                "cos_tea_uni": cos_mean,
            },
            batch_size=[],
        )

    def extra_repr(self) -> str:
        return (
            f"w7={self.w7}, w8={self.w8}, c_mt={self.c_mt}, c_ms={self.c_ms}, "
            f"mask_ratio={self.mask_ratio}"
        )
