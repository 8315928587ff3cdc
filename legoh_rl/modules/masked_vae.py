"""Masked VAE over joint actions, the feature space of Hierarchical Latent Matching (HLM).

Paper: "Hierarchical Latent Matching Metric" (Eqs. 2-9) and appendix "Network Architectures /
Masked VAE for HLM": residual fully connected encoder and decoder, a sine-cosine positional
embedding per joint, ReLU activations, two linear heads (mean and log-variance) at the end of
the encoder and a sigmoid on the decoder output.

Action space and the unit mapping
---------------------------------
The VAE reads and writes actions ``a`` in the policy's action space (``q* = q_default + 0.25 a``,
``(..., A)``). Internally it works in the unit cube, which the decoder's sigmoid can reach::

    to_unit(a)   = (clamp(a, low, high) - low) / (high - low)        # in [0, 1]
    from_unit(u) = low + u * (high - low)                              # exact inverse on [low, high]

The configured bounds default to ``-5 .. 5``, the env's action clip (``EnvConfig.action_clip``),
which holds every action the env accepts. Teacher actions usually span a much narrower range
and, measured, a VAE whose inputs fill only a small slice of ``[0, 1]`` collapses to an
uninformative latent. :meth:`MaskedVAE.fit_bounds` therefore narrows the bounds per joint to a
sample of teacher actions (min/max widened by a margin); ``MaskedVAELoss`` does it on the first
batch it sees unless told not to. The bounds are buffers (saved with the weights) and stay
fixed afterwards: the latent's meaning depends on them. Values outside the bounds are clamped
(zero gradient there).

Joint embedding
---------------
Each joint ``j`` becomes a token ``[u_j, pe_j]`` where ``pe_j`` is the fixed (non-trained)
transformer-style sine-cosine embedding of the joint index ``j`` (``joint_embed_dim`` values).
One linear layer + ReLU *shared by all joints* maps every token to ``joint_embed_dim``
features, so only ``pe_j`` tells the joints apart at that stage; the ``A`` token features are
then flattened and fed to the residual MLP.

Masking
-------
:func:`mask_joints` replaces exactly ``num_masked_joints(ratio, A)`` randomly chosen joints per
sample by a fill value. :meth:`MaskedVAE.mask_joints` uses the mid-point of the action bounds:
``0.5`` in unit space, i.e. the zero action (the default joint pose) for the symmetric default
bounds and the middle of the teacher's range after :meth:`MaskedVAE.fit_bounds`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

__all__ = [
    "MaskedVAE",
    "MaskedVAEConfig",
    "MaskedVAEDecoder",
    "MaskedVAEEncoder",
    "ResidualFC",
    "make_masked_vae_module",
    "mask_joints",
    "num_masked_joints",
    "sincos_joint_embedding",
]


@dataclass
class MaskedVAEConfig:
    """Configuration of :class:`MaskedVAE`.

    Attributes:
        action_dim: number of joints ``A`` (H1: 10, G1: 12).
        latent_dim: size of the latent ``z_vae``.
        hidden_dim: width of the residual MLP.
        num_blocks: residual FC blocks in the encoder and (as many) in the decoder.
        joint_embed_dim: size of the sine-cosine joint-index embedding and of each joint's
            token feature (even, >= 2).
        action_low: lower action bound, a scalar for all joints or one value per joint
            (default -5, the env's action clip; see :meth:`MaskedVAE.fit_bounds`).
        action_high: upper action bound, a scalar or one value per joint; ``> action_low``.
    """

    action_dim: int = 10
    latent_dim: int = 16
    hidden_dim: int = 128
    num_blocks: int = 2
    joint_embed_dim: int = 8
    action_low: float | Sequence[float] = -5.0
    action_high: float | Sequence[float] = 5.0

    def __post_init__(self) -> None:
        for name in ("action_dim", "latent_dim", "hidden_dim", "joint_embed_dim"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"MaskedVAEConfig.{name} must be a positive int, got {value!r}")
        if not isinstance(self.num_blocks, int) or self.num_blocks < 0:
            raise ValueError(
                f"MaskedVAEConfig.num_blocks must be a non-negative int, got {self.num_blocks!r}"
            )
        if self.joint_embed_dim % 2:
            raise ValueError(
                f"MaskedVAEConfig.joint_embed_dim must be even (sin/cos pairs), "
                f"got {self.joint_embed_dim}"
            )
        low, high = self.bounds()
        bad = (high <= low).nonzero().flatten().tolist()
        if bad:
            raise ValueError(
                f"MaskedVAEConfig: action_high must exceed action_low for every joint; "
                f"joints {bad} have low={low[bad].tolist()} high={high[bad].tolist()}"
            )
        if not (torch.isfinite(low).all() and torch.isfinite(high).all()):
            raise ValueError(
                f"MaskedVAEConfig: action bounds must be finite, got low={self.action_low!r} "
                f"high={self.action_high!r}"
            )

    def bounds(self) -> tuple[Tensor, Tensor]:
        """Return ``(low, high)`` as float32 tensors of shape ``(A,)``."""
        return (
            _per_joint(self.action_low, self.action_dim, "action_low"),
            _per_joint(self.action_high, self.action_dim, "action_high"),
        )


def _per_joint(value: float | Sequence[float], action_dim: int, name: str) -> Tensor:
    t = torch.as_tensor(value, dtype=torch.float32)
    if t.ndim == 0:
        return t.expand(action_dim).clone()
    if t.shape != (action_dim,):
        raise ValueError(
            f"MaskedVAEConfig.{name} must be a scalar or have {action_dim} values "
            f"(action_dim), got shape {tuple(t.shape)}"
        )
    return t.clone()


def sincos_joint_embedding(num_joints: int, dim: int) -> Tensor:
    """Fixed sine-cosine embedding of the joint indices ``0..num_joints-1``.

    ``pe[j, 2i] = sin(j / 10000^(2i/dim))``, ``pe[j, 2i+1] = cos(j / 10000^(2i/dim))``
    (the transformer positional encoding).

    Returns:
        Tensor of shape ``(num_joints, dim)``.
    """
    if dim % 2 or dim < 2:
        raise ValueError(f"embedding dim must be even and >= 2, got {dim}")
    pos = torch.arange(num_joints, dtype=torch.float32).unsqueeze(1)
    freq = torch.exp(-math.log(10000.0) * torch.arange(0, dim, 2, dtype=torch.float32) / dim)
    pe = torch.zeros(num_joints, dim)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq)
    return pe


class ResidualFC(nn.Module):
    """Residual fully connected block: ``y = relu(x + W2 relu(W1 x))``, shape ``(..., width)``."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(width, width)
        self.fc2 = nn.Linear(width, width)

    def forward(self, x: Tensor) -> Tensor:
        return torch.relu(x + self.fc2(torch.relu(self.fc1(x))))


class MaskedVAEEncoder(nn.Module):
    """Encoder ``q(z | a)`` on unit-space actions.

    ``forward(u)``: ``u`` of shape ``(..., A)`` in ``[0, 1]`` -> ``(mu, logvar)``, each
    ``(..., latent_dim)``. Joint tokens ``[u_j, pe_j]`` -> shared Linear+ReLU -> flatten ->
    Linear+ReLU -> ``num_blocks`` x :class:`ResidualFC` -> two linear heads.
    """

    def __init__(self, cfg: MaskedVAEConfig) -> None:
        super().__init__()
        self.action_dim = cfg.action_dim
        e = cfg.joint_embed_dim
        self.register_buffer("joint_pe", sincos_joint_embedding(cfg.action_dim, e))
        self.token = nn.Linear(1 + e, e)
        self.proj = nn.Linear(cfg.action_dim * e, cfg.hidden_dim)
        self.blocks = nn.Sequential(*[ResidualFC(cfg.hidden_dim) for _ in range(cfg.num_blocks)])
        self.mu = nn.Linear(cfg.hidden_dim, cfg.latent_dim)
        self.logvar = nn.Linear(cfg.hidden_dim, cfg.latent_dim)

    def forward(self, u: Tensor) -> tuple[Tensor, Tensor]:
        pe = self.joint_pe.to(u.dtype).expand(*u.shape, self.joint_pe.shape[-1])
        tokens = torch.cat([u.unsqueeze(-1), pe], dim=-1)  # (..., A, 1 + E)
        h = torch.relu(self.token(tokens)).flatten(-2)  # (..., A * E)
        h = self.blocks(torch.relu(self.proj(h)))
        return self.mu(h), self.logvar(h)


class MaskedVAEDecoder(nn.Module):
    """Decoder ``p(a | z)``: ``z`` ``(..., latent_dim)`` -> unit-space actions ``(..., A)`` in (0, 1).

    Linear+ReLU -> ``num_blocks`` x :class:`ResidualFC` -> Linear -> sigmoid.
    """

    def __init__(self, cfg: MaskedVAEConfig) -> None:
        super().__init__()
        self.proj = nn.Linear(cfg.latent_dim, cfg.hidden_dim)
        self.blocks = nn.Sequential(*[ResidualFC(cfg.hidden_dim) for _ in range(cfg.num_blocks)])
        self.out = nn.Linear(cfg.hidden_dim, cfg.action_dim)

    def forward(self, z: Tensor) -> Tensor:
        return torch.sigmoid(self.out(self.blocks(torch.relu(self.proj(z)))))


def num_masked_joints(ratio: float, action_dim: int) -> int:
    """Number of joints masked per sample: ``min(floor(ratio * A + 0.5), A - 1)``.

    Rounds half up, and never masks every joint (an all-masked input carries no information;
    only ratios within ``0.5 / A`` of 1 are affected). ``ratio`` must lie in ``[0, 1)``.
    """
    if isinstance(ratio, bool) or not isinstance(ratio, (int, float)) or not (0.0 <= ratio < 1.0):
        raise ValueError(f"masking ratio must be a number in [0, 1), got {ratio!r}")
    if action_dim < 1:
        raise ValueError(f"action_dim must be >= 1, got {action_dim}")
    return min(int(math.floor(ratio * action_dim + 0.5)), action_dim - 1)


def mask_joints(
    a: Tensor,
    ratio: float,
    generator: torch.Generator | None = None,
    *,
    fill_value: float | Tensor = 0.0,
) -> tuple[Tensor, Tensor]:
    """Randomly mask joints of actions ``a``.

    Every sample (every index of the leading dimensions) gets exactly
    ``k = num_masked_joints(ratio, A)`` masked joints, chosen uniformly without replacement;
    masked entries are replaced by ``fill_value`` (a scalar, or a ``(A,)`` tensor of per-joint
    values). The default ``0.0`` is the zero action, i.e. the default joint pose and the
    mid-point of symmetric action bounds. Gradients flow to the unmasked entries of ``a``.

    Args:
        a: actions of shape ``(..., A)``.
        ratio: masking ratio in ``[0, 1)``.
        generator: optional ``torch.Generator`` (on ``a``'s device) for reproducible masks.
        fill_value: value written into masked joints.

    Returns:
        ``(a_masked, mask)``: ``a_masked`` has ``a``'s shape; ``mask`` is a bool tensor of the
        same shape, ``True`` where a joint was masked.
    """
    if a.ndim < 1:
        raise ValueError(f"mask_joints expects actions of shape (..., A), got a scalar {a!r}")
    action_dim = a.shape[-1]
    k = num_masked_joints(ratio, action_dim)
    mask = torch.zeros(a.shape, dtype=torch.bool, device=a.device)
    if k > 0:
        scores = torch.rand(a.shape, generator=generator, device=a.device)
        idx = scores.argsort(dim=-1)[..., :k]
        mask.scatter_(-1, idx, True)
    fill = torch.as_tensor(fill_value, dtype=a.dtype, device=a.device)
    if fill.ndim > 0 and fill.shape != (action_dim,):
        raise ValueError(
            f"fill_value must be a scalar or have {action_dim} values, got shape {tuple(fill.shape)}"
        )
    return torch.where(mask, fill.expand_as(a), a), mask


class MaskedVAE(nn.Module):
    """Masked VAE over joint actions (LEGO-H HLM).

    Inputs and outputs are in the action space; ``to_unit`` / ``from_unit`` map to and from
    the ``[0, 1]`` space the networks work in (see the module docstring).

    Args:
        cfg: a :class:`MaskedVAEConfig` (defaults if ``None``).

    Attributes:
        encoder: :class:`MaskedVAEEncoder` (unit space in, ``(mu, logvar)`` out). Loss modules
            that need a frozen encoder call it functionally (see ``HLMLoss``).
        decoder: :class:`MaskedVAEDecoder` (latent in, unit space out).
        action_low, action_high: buffers of shape ``(A,)``.
        bounds_fitted: bool buffer, True once :meth:`fit_bounds` has run.
    """

    def __init__(self, cfg: MaskedVAEConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg = cfg if cfg is not None else MaskedVAEConfig()
        low, high = cfg.bounds()
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)
        self.register_buffer("bounds_fitted", torch.tensor(False))
        self.encoder = MaskedVAEEncoder(cfg)
        self.decoder = MaskedVAEDecoder(cfg)

    @property
    def action_dim(self) -> int:
        return self.cfg.action_dim

    @property
    def latent_dim(self) -> int:
        return self.cfg.latent_dim

    @property
    def fill_value(self) -> Tensor:
        """Per-joint fill value of masked joints: the mid-point of the bounds, shape ``(A,)``."""
        return 0.5 * (self.action_low + self.action_high)

    @torch.no_grad()
    def fit_bounds(
        self, actions: Tensor, margin: float = 0.1, min_width: float = 1e-2
    ) -> tuple[Tensor, Tensor]:
        """Set the per-joint bounds to the range of ``actions`` widened by ``margin``.

        ``low = min - margin * (max - min)``, ``high = max + margin * (max - min)`` per joint,
        over every leading dimension of ``actions`` (``(..., A)``, finite); joints whose width
        would be below ``min_width`` are widened symmetrically to ``min_width``. Replaces the
        ``action_low`` / ``action_high`` buffers (new tensors, so autograd graphs that used the
        old bounds remain valid) and sets ``bounds_fitted``; ``cfg`` keeps the configured
        bounds. Call it before training: changing the bounds afterwards changes what the latent
        means.

        Returns:
            ``(low, high)``, each ``(A,)``.
        """
        self.check_actions(actions)
        if not margin >= 0:
            raise ValueError(f"fit_bounds: margin must be >= 0, got {margin!r}")
        if not min_width > 0:
            raise ValueError(f"fit_bounds: min_width must be > 0, got {min_width!r}")
        flat = actions.detach().reshape(-1, self.cfg.action_dim)
        if flat.shape[0] == 0:
            raise ValueError("fit_bounds needs at least one action")
        if not torch.isfinite(flat).all():
            raise ValueError("fit_bounds: actions contain NaN or inf values")
        lo, hi = flat.min(0).values, flat.max(0).values
        width = hi - lo
        lo, hi = lo - margin * width, hi + margin * width
        pad = (min_width - (hi - lo)).clamp_min(0) / 2
        lo, hi = lo - pad, hi + pad
        # new tensors rather than in-place copies: graphs built with the old bounds (e.g. an
        # HLM term computed earlier in the same step) stay valid for backward
        self.action_low = lo.to(self.action_low)
        self.action_high = hi.to(self.action_high)
        self.bounds_fitted.fill_(True)
        return self.action_low.clone(), self.action_high.clone()

    def check_actions(self, a: Tensor, name: str = "actions") -> None:
        """Raise ``ValueError`` unless ``a`` has shape ``(..., action_dim)``."""
        if a.ndim < 1 or a.shape[-1] != self.cfg.action_dim:
            raise ValueError(
                f"MaskedVAE expects {name} of shape (..., {self.cfg.action_dim}) "
                f"(action_dim={self.cfg.action_dim}), got shape {tuple(a.shape)}"
            )

    def to_unit(self, a: Tensor) -> Tensor:
        """Map actions ``(..., A)`` to ``[0, 1]``: ``(clamp(a, low, high) - low) / (high - low)``."""
        self.check_actions(a)
        low, high = self.action_low.to(a.dtype), self.action_high.to(a.dtype)
        return (torch.clamp(a, low, high) - low) / (high - low)

    def from_unit(self, u: Tensor) -> Tensor:
        """Inverse of :meth:`to_unit` on the bounds: ``low + u * (high - low)``, ``(..., A)``."""
        self.check_actions(u, "unit-space actions")
        low, high = self.action_low.to(u.dtype), self.action_high.to(u.dtype)
        return low + u * (high - low)

    def encode(self, a: Tensor) -> tuple[Tensor, Tensor]:
        """``q(z | a)``: actions ``(..., A)`` (action space; ``to_unit`` is applied here) ->
        ``(mu, logvar)``, each ``(..., latent_dim)``."""
        return self.encoder(self.to_unit(a))

    def latent(self, a: Tensor) -> Tensor:
        """``Enc(a)`` of HLM: the encoder mean ``mu``, shape ``(..., latent_dim)``."""
        return self.encode(a)[0]

    def decode(self, z: Tensor) -> Tensor:
        """``Dec(z)``: latent ``(..., latent_dim)`` -> actions ``(..., A)`` in the action space
        (within ``(low, high)``, the sigmoid output mapped by ``from_unit``)."""
        if z.ndim < 1 or z.shape[-1] != self.cfg.latent_dim:
            raise ValueError(
                f"MaskedVAE.decode expects latents of shape (..., {self.cfg.latent_dim}), "
                f"got shape {tuple(z.shape)}"
            )
        return self.from_unit(self.decoder(z))

    @staticmethod
    def reparameterize(
        mu: Tensor, logvar: Tensor, generator: torch.Generator | None = None
    ) -> Tensor:
        """Sample ``z = mu + exp(logvar / 2) * eps``, ``eps ~ N(0, I)``; shapes ``(..., Z)``."""
        eps = torch.randn(mu.shape, generator=generator, device=mu.device, dtype=mu.dtype)
        return mu + torch.exp(0.5 * logvar) * eps

    def forward(
        self,
        a: Tensor,
        *,
        sample: bool | None = None,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Reconstruct actions.

        Args:
            a: actions ``(..., A)`` in the action space.
            sample: decode a reparameterised sample (``True``) or the mean (``False``);
                ``None`` (default) samples in training mode and uses the mean in eval mode.
            generator: optional generator for the sampling noise.

        Returns:
            ``(a_rec, mu, logvar)``: ``a_rec`` ``(..., A)`` in the action space,
            ``mu`` and ``logvar`` ``(..., latent_dim)``.
        """
        mu, logvar = self.encode(a)
        if sample is None:
            sample = self.training
        z = self.reparameterize(mu, logvar, generator) if sample else mu
        return self.decode(z), mu, logvar

    def mask_joints(
        self, a: Tensor, ratio: float, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor]:
        """:func:`mask_joints` with this VAE's fill value (the mid-point of the bounds)."""
        self.check_actions(a)
        return mask_joints(a, ratio, generator, fill_value=self.fill_value.to(a.dtype))


def make_masked_vae_module(
    cfg: MaskedVAEConfig | MaskedVAE | None = None,
    in_key: str | tuple[str, ...] = "action_tea",
    out_keys: Sequence[str | tuple[str, ...]] = ("vae_action_rec", "vae_mu", "vae_logvar"),
) -> TensorDictModule:
    """Wrap a :class:`MaskedVAE` in a ``TensorDictModule``.

    Reads ``in_key`` (``(*B, A)``) and writes ``out_keys`` = (reconstruction ``(*B, A)``,
    ``mu`` ``(*B, Z)``, ``logvar`` ``(*B, Z)``); the reconstruction decodes a sample in
    training mode and the mean in eval mode. Pass an existing VAE to share its weights.
    """
    vae = cfg if isinstance(cfg, MaskedVAE) else MaskedVAE(cfg)
    out_keys = list(out_keys)
    if len(out_keys) != 3:
        raise ValueError(
            f"make_masked_vae_module needs 3 out_keys (reconstruction, mu, logvar), got {out_keys}"
        )
    return TensorDictModule(vae, in_keys=[in_key], out_keys=out_keys)
