"""LEGO-H loss modules.

- :func:`make_ppo_loss` / :class:`PPOConfig`: torchrl's ``ClipPPOLoss`` + ``GAE`` with rsl_rl
  defaults; :class:`AdaptiveKLScheduler` and :func:`policy_kl` for the KL-adaptive learning rate.
- :class:`DAggerLoss`: imitation L_im (paper Eq. 1).
- :class:`MaskedVAELoss`: masked-VAE reconstruction L_rec (Eqs. 2-5).
- :class:`HLMLoss`: Hierarchical Latent Matching L_hie (Eqs. 6-9).

Every loss returns a TensorDict whose ``loss_*`` entries a recipe sums; see docs/objectives.md.
Every loss (and :func:`policy_kl`) reads the valid-step mask at :data:`VALID_MASK_KEY`,
torchrl's ``("collector", "mask")``, unless remapped with ``set_keys(mask=...)``.
"""

from legoh_rl.objectives._common import VALID_MASK_KEY
from legoh_rl.objectives.dagger import DAggerLoss
from legoh_rl.objectives.hlm import HLMLoss, cosine_similarity
from legoh_rl.objectives.masked_vae_loss import MaskedVAELoss
from legoh_rl.objectives.ppo import (
    AdaptiveKLScheduler,
    PPOConfig,
    gaussian_kl,
    make_ppo_loss,
    policy_kl,
    set_loss_coefficients,
)

__all__ = [
    "AdaptiveKLScheduler",
    "DAggerLoss",
    "HLMLoss",
    "MaskedVAELoss",
    "PPOConfig",
    "VALID_MASK_KEY",
    "cosine_similarity",
    "gaussian_kl",
    "make_ppo_loss",
    "set_loss_coefficients",
    "policy_kl",
]
