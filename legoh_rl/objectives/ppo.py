"""PPO with legged-locomotion (rsl_rl) defaults on top of torchrl's ClipPPOLoss and GAE.

Nothing here re-implements PPO: :func:`make_ppo_loss` configures
:class:`torchrl.objectives.ClipPPOLoss` and its :class:`torchrl.objectives.value.GAE`
estimator; :class:`AdaptiveKLScheduler` is rsl_rl's KL-adaptive learning rate and
:func:`policy_kl` measures the KL it needs from a batch.

Keys (torchrl defaults, matching ``docs/keys.md``): the actor writes ``loc`` and ``scale``
and samples ``action`` with its log-probability ``action_log_prob``; the critic writes
``state_value``; GAE writes ``advantage`` and ``value_target``. The collector stores the
rollout-time ``loc`` / ``scale`` in the batch: these are the *old* distribution parameters
:func:`policy_kl` compares to the current actor's. The loss's output also holds the current
policy's ``policy_loc`` / ``policy_scale`` from its own forward pass (:class:`PPOLossWithPolicy`),
from which :func:`rollout_kl` gives the KL to the rollout policy without another actor pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.utils import ValueEstimators
from torchrl.objectives.value import GAE

from legoh_rl.kinds import Choice, Flag, Integer, Number, check_fields, setting
from legoh_rl.objectives._common import VALID_MASK_KEY

__all__ = [
    "AdaptiveKLScheduler",
    "PPOConfig",
    "PPOLossWithPolicy",
    "gaussian_kl",
    "make_ppo_loss",
    "minibatch_keys",
    "policy_kl",
    "rollout_kl",
    "set_loss_coefficients",
]


@dataclass
class PPOConfig:
    """PPO hyper-parameters, defaults from rsl_rl / legged_gym (used by the paper's pipeline).

    Loss (passed to ``ClipPPOLoss`` / ``GAE``):
        clip_epsilon: ratio clip (0.2).
        entropy_coeff: entropy bonus weight (0.01).
        critic_coeff: value loss weight (1.0, rsl_rl ``value_loss_coef``).
        loss_critic_type: ``"l2"``: rsl_rl's squared error ``(V - R)^2`` (no 1/2).
        clip_value: clipped value loss (rsl_rl ``use_clipped_value_loss``): the value
            prediction may move at most ``clip_epsilon`` from the rollout value.
        normalize_advantage: standardise advantages (per mini-batch in torchrl).
        gamma, lmbda: GAE discount (0.99) and lambda (0.95).

    Optimisation (read by recipes; not used by the loss):
        learning_rate: initial Adam learning rate (1e-3).
        desired_kl: target of :class:`AdaptiveKLScheduler` (0.01).
        min_lr, max_lr: learning-rate clamp of the scheduler (1e-5, 1e-2).
        max_grad_norm: gradient-norm clip (1.0).
        num_epochs, num_minibatches: passes over each batch (5) and mini-batches per pass (4).
    """

    clip_epsilon: float = setting(0.2, Number(0, 1, low_open=True, high_open=True))
    entropy_coeff: float = setting(0.01, Number(0))
    critic_coeff: float = setting(1.0, Number(0))
    loss_critic_type: str = setting("l2", Choice(("l1", "l2", "smooth_l1")))
    clip_value: bool = setting(True, Flag())
    normalize_advantage: bool = setting(True, Flag())
    gamma: float = setting(0.99, Number(0, 1))
    lmbda: float = setting(0.95, Number(0, 1))
    learning_rate: float = setting(1e-3, Number(0, low_open=True))
    desired_kl: float = setting(0.01, Number(0, low_open=True))
    min_lr: float = setting(1e-5, Number(0, low_open=True))
    max_lr: float = setting(1e-2, Number(0, low_open=True))
    max_grad_norm: float = setting(1.0, Number(0, low_open=True))
    num_epochs: int = setting(5, Integer(1))
    num_minibatches: int = setting(4, Integer(1))

    def __post_init__(self) -> None:
        check_fields(self)  # each field against its kind (legoh_rl/kinds.py); below: how they combine
        if not 0 < self.min_lr <= self.learning_rate <= self.max_lr:
            raise ValueError(
                f"PPOConfig needs 0 < min_lr <= learning_rate <= max_lr, got min_lr="
                f"{self.min_lr}, learning_rate={self.learning_rate}, max_lr={self.max_lr}"
            )


class PPOLossWithPolicy(ClipPPOLoss):
    """torchrl's :class:`~torchrl.objectives.ClipPPOLoss`, unchanged, whose output also holds the
    current policy's distribution parameters from the loss's own forward pass.

    ``loss(minibatch)`` adds ``policy_loc`` and ``policy_scale`` (``(*B, A)``, detached: the mean
    and standard deviation of the distribution the objective's log-probabilities came from) to
    torchrl's entries, so that the KL to the rollout policy (:func:`rollout_kl`) costs no further
    actor pass. Losses, gradients and state dict are ``ClipPPOLoss``'s to the bit.

    Only for a single (not composite) distribution; with a composite one the two entries are
    absent.
    """

    def _get_cur_log_prob(self, tensordict: TensorDictBase, params=None):
        log_prob, dist, is_composite = super()._get_cur_log_prob(tensordict, params)
        if params is None and not is_composite:  # the current parameters (not a delayed actor's)
            self._policy = (dist.mean.detach(), dist.stddev.detach())
        return log_prob, dist, is_composite

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._policy = None
        out = super().forward(tensordict)
        if self._policy is not None:
            out.set("policy_loc", self._policy[0])
            out.set("policy_scale", self._policy[1])
        self._policy = None  # the minibatch's tensors are held by the output only
        return out


def minibatch_keys(loss: ClipPPOLoss, *extra: NestedKey) -> list[NestedKey]:
    """The entries ``loss`` reads from a minibatch once GAE has written ``advantage``,
    ``value_target`` and ``state_value`` (plus ``extra``, e.g. the rollout ``loc`` / ``scale``
    that :func:`policy_kl` reads), each once.

    Indexing a batch's minibatches out of ``batch.select(*minibatch_keys(loss), strict=False)``
    instead of the whole batch gives the loss the same tensors while skipping every entry it
    never reads (the next observations, reward terms, episode counters, ...): indexing costs one
    gather per entry and minibatch. The padding masks the loss honours (``("collector", "mask")``,
    ``shifted_valid``: torchrl's own list, ``_loss_mask_keys``) are included.
    """
    keys = loss.tensor_keys
    wanted = [*loss.actor_network.in_keys, *loss.critic_network.in_keys, keys.action, keys.sample_log_prob,
              keys.advantage, keys.value_target, keys.value, *loss._loss_mask_keys(), *extra]
    unique: list[NestedKey] = []
    for key in wanted:
        key = key[0] if isinstance(key, tuple) and len(key) == 1 else key  # ("obs",) is "obs"
        if key not in unique:
            unique.append(key)
    return unique


def make_ppo_loss(
    actor: TensorDictModuleBase,
    critic: TensorDictModuleBase,
    cfg: PPOConfig | None = None,
) -> tuple[PPOLossWithPolicy, GAE]:
    """Build torchrl's ``ClipPPOLoss`` (as :class:`PPOLossWithPolicy`) with a ``GAE`` value
    estimator, rsl_rl defaults.

    Args:
        actor: a probabilistic actor (e.g. ``ProbabilisticActor`` over ``loc``/``scale`` with
            ``IndependentNormal``) returning ``action`` and ``action_log_prob``.
        critic: a value module writing ``state_value`` (``(*B, 1)``).
        cfg: hyper-parameters (:class:`PPOConfig` defaults if ``None``).

    Returns:
        ``(loss, gae)``. ``gae`` is ``loss.value_estimator``: call ``gae(batch)`` under
        ``torch.no_grad()`` once per collected batch to write ``advantage``,
        ``value_target`` and ``state_value`` (the rollout value the clipped value loss uses),
        then ``loss(minibatch)`` returns ``loss_objective``, ``loss_critic``,
        ``loss_entropy`` (sum them), diagnostics (``kl_approx``, ``clip_fraction``, ...) and the
        current policy's ``policy_loc`` / ``policy_scale`` (:class:`PPOLossWithPolicy`).
        Padding masks written by torchrl (``("collector", "mask")``,
        :data:`~legoh_rl.objectives.VALID_MASK_KEY`, the default of every LEGO-H loss) are
        honoured by the loss (torchrl's ``loss_mask_key="auto"``, which also ANDs the value
        estimator's ``shifted_valid``).
    """
    cfg = cfg if cfg is not None else PPOConfig()
    loss = PPOLossWithPolicy(
        actor,
        critic,
        clip_epsilon=cfg.clip_epsilon,
        entropy_bonus=cfg.entropy_coeff > 0,
        entropy_coeff=cfg.entropy_coeff,
        critic_coeff=cfg.critic_coeff,
        loss_critic_type=cfg.loss_critic_type,
        normalize_advantage=cfg.normalize_advantage,
        clip_value=cfg.clip_value,
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.gamma, lmbda=cfg.lmbda)
    return loss, loss.value_estimator


def set_loss_coefficients(loss: ClipPPOLoss, cfg: PPOConfig) -> None:
    """Write ``cfg``'s clip range and entropy/critic weights into ``loss``'s buffers.

    ``ClipPPOLoss`` keeps these as buffers, so ``load_state_dict`` of a checkpoint restores the
    values of the run that wrote it. Call this after loading to make the current config win (a
    resumed run with a new entropy weight, for example).

    Raises:
        ValueError: ``cfg.entropy_coeff > 0`` but ``loss`` was built without an entropy bonus.
    """
    if cfg.entropy_coeff > 0 and not loss.entropy_bonus:
        raise ValueError(f"entropy_coeff={cfg.entropy_coeff} needs a loss built with an entropy bonus")
    loss.clip_epsilon.fill_(cfg.clip_epsilon)
    loss.critic_coeff.fill_(cfg.critic_coeff)
    if loss.entropy_bonus:
        loss.entropy_coeff.fill_(cfg.entropy_coeff)


def gaussian_kl(old_loc: Tensor, old_scale: Tensor, new_loc: Tensor, new_scale: Tensor) -> Tensor:
    """``KL(N(old_loc, old_scale) || N(new_loc, new_scale))`` for diagonal Gaussians.

    Summed over the last (action) dimension, as rsl_rl::

        sum_i log(s1_i / s0_i) + (s0_i^2 + (m0_i - m1_i)^2) / (2 s1_i^2) - 1/2

    Shapes: ``(*B, A)`` each -> ``(*B,)``.
    """
    return (
        torch.log(new_scale / old_scale)
        + (old_scale.pow(2) + (old_loc - new_loc).pow(2)) / (2.0 * new_scale.pow(2))
        - 0.5
    ).sum(-1)


def policy_kl(
    actor: TensorDictModuleBase,
    tensordict: TensorDictBase,
    *,
    old_loc_key: NestedKey = "loc",
    old_scale_key: NestedKey = "scale",
    new_loc_key: NestedKey = "loc",
    new_scale_key: NestedKey = "scale",
    mask_key: NestedKey | None = VALID_MASK_KEY,
) -> Tensor:
    """Mean KL between the rollout policy stored in a batch and the current ``actor``.

    The old parameters are read from ``tensordict`` at ``old_loc_key`` / ``old_scale_key``
    (written by the collector, ``(*B, A)``); the new ones by running ``actor`` (no grad) on the
    entries it reads, which leaves ``tensordict`` untouched, and reading ``new_loc_key`` /
    ``new_scale_key`` from its output. A probabilistic actor (one with ``get_dist_params``, as
    torchrl's ``ProbabilisticActor``) runs its parameter network only: no action is drawn and no
    log-probability computed, which changes none of the values. Returns the scalar mean of
    :func:`gaussian_kl` over the samples whose bool mask at ``mask_key`` (default
    ``("collector", "mask")``, :data:`~legoh_rl.objectives.VALID_MASK_KEY`) is True (all
    samples if the key is absent or None).
    """
    _rollout_params(tensordict, old_loc_key, old_scale_key)  # before running the actor
    with torch.no_grad():
        inputs = tensordict.select(*actor.in_keys, strict=False)
        out = actor.get_dist_params(inputs) if hasattr(actor, "get_dist_params") else actor(inputs)
        return rollout_kl(tensordict, out.get(new_loc_key), out.get(new_scale_key), old_loc_key=old_loc_key,
                          old_scale_key=old_scale_key, mask_key=mask_key)


def rollout_kl(
    tensordict: TensorDictBase,
    new_loc: Tensor,
    new_scale: Tensor,
    *,
    old_loc_key: NestedKey = "loc",
    old_scale_key: NestedKey = "scale",
    mask_key: NestedKey | None = VALID_MASK_KEY,
) -> Tensor:
    """Mean KL between the rollout policy stored in a batch and the diagonal Gaussian
    ``(new_loc, new_scale)`` (``(*B, A)`` each: e.g. the ``policy_loc`` / ``policy_scale`` of a
    :class:`PPOLossWithPolicy` output), without gradient.

    The old parameters are read from ``tensordict`` at ``old_loc_key`` / ``old_scale_key``
    (``(*B, A)``). Returns the scalar mean of :func:`gaussian_kl` over the samples whose bool
    mask at ``mask_key`` (default ``("collector", "mask")``,
    :data:`~legoh_rl.objectives.VALID_MASK_KEY`) is True (all samples if the key is absent or
    None).

    Raises:
        KeyError: the rollout parameters are not in ``tensordict`` (both keys named).
        ValueError: the mask's shape does not match the KL's batch shape (both shapes named).
    """
    old_loc, old_scale = _rollout_params(tensordict, old_loc_key, old_scale_key)
    with torch.no_grad():
        kl = gaussian_kl(old_loc, old_scale, new_loc.detach(), new_scale.detach())
        mask = tensordict.get(mask_key, None) if mask_key is not None else None
        if mask is None:
            return kl.mean()
        while mask.ndim > kl.ndim and mask.shape[-1] == 1:
            mask = mask.squeeze(-1)
        if mask.shape != kl.shape:
            raise ValueError(
                f"mask {mask_key!r} of shape {tuple(mask.shape)} does not match the KL's "
                f"batch shape {tuple(kl.shape)}"
            )
        return torch.where(mask, kl, torch.zeros_like(kl)).sum() / mask.sum().clamp_min(1)


def _rollout_params(tensordict: TensorDictBase, loc_key: NestedKey, scale_key: NestedKey) -> tuple[Tensor, Tensor]:
    """The rollout policy's ``(loc, scale)`` stored in a batch (a KeyError naming both keys when absent)."""
    old_loc = tensordict.get(loc_key, None)
    old_scale = tensordict.get(scale_key, None)
    if old_loc is None or old_scale is None:
        raise KeyError(
            f"the KL to the rollout policy needs its distribution at {loc_key!r} and {scale_key!r}; "
            "make the collector keep the actor's loc/scale outputs"
        )
    return old_loc, old_scale


class AdaptiveKLScheduler:
    """rsl_rl's KL-adaptive learning rate.

    After each measurement ``kl`` (e.g. :func:`policy_kl` on a mini-batch)::

        if kl > 2 * target_kl:            lr = max(min_lr, lr / factor)
        elif 0 < kl < target_kl / 2:      lr = min(max_lr, lr * factor)

    and the new ``lr`` is written into every param group of ``optimizer``.

    Args:
        optimizer: the policy/critic optimizer (give the masked VAE its own optimizer).
        target_kl: desired KL (0.01).
        factor: multiplicative step (1.5).
        min_lr, max_lr: clamp (1e-5, 1e-2).
    """

    def __init__(
        self,
        optimizer: torch.optim.Optimizer,
        target_kl: float = 0.01,
        *,
        factor: float = 1.5,
        min_lr: float = 1e-5,
        max_lr: float = 1e-2,
    ) -> None:
        if not target_kl > 0:
            raise ValueError(f"target_kl must be > 0, got {target_kl!r}")
        if not factor > 1:
            raise ValueError(f"factor must be > 1, got {factor!r}")
        if not 0 < min_lr <= max_lr:
            raise ValueError(f"need 0 < min_lr <= max_lr, got min_lr={min_lr!r}, max_lr={max_lr!r}")
        self.optimizer = optimizer
        self.target_kl = float(target_kl)
        self.factor = float(factor)
        self.min_lr = float(min_lr)
        self.max_lr = float(max_lr)
        self.lr = min(max(float(optimizer.param_groups[0]["lr"]), self.min_lr), self.max_lr)
        self._apply()

    def _apply(self) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = self.lr

    def step(self, kl: float | Tensor) -> float:
        """Update the learning rate from the measured ``kl``; returns the new learning rate."""
        kl = float(kl.item() if isinstance(kl, Tensor) else kl)
        if not math.isfinite(kl):
            raise ValueError(f"AdaptiveKLScheduler.step got a non-finite KL: {kl}")
        if kl > 2.0 * self.target_kl:
            self.lr = max(self.min_lr, self.lr / self.factor)
        elif 0.0 < kl < 0.5 * self.target_kl:
            self.lr = min(self.max_lr, self.lr * self.factor)
        self._apply()
        return self.lr

    def state_dict(self) -> dict[str, float]:
        return {"lr": self.lr}

    def load_state_dict(self, state: dict[str, float]) -> None:
        self.lr = float(state["lr"])
        self._apply()
