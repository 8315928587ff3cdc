"""DAgger imitation loss L_im of LEGO-H (paper Eq. 1, "Unified Hiking Policy Learning with Vision")."""

from __future__ import annotations

from dataclasses import dataclass

import torch.nn.functional as F
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.objectives import LossModule

from legoh_rl.objectives._common import (
    VALID_MASK_KEY,
    check_reduction,
    check_same_shape,
    check_weight,
    get_entry,
    get_padding_mask,
    reduce_samples,
    run_student,
)

__all__ = ["DAggerLoss"]


class DAggerLoss(LossModule):
    r"""Latent, goal and action imitation of the frozen oracle (Eq. 1)::

        L_im = w1 ||z_tea - z_uni||^2 + w2 SmoothL1(G_tea, G_uni) + w3 SmoothL1(a_tea, a_uni)

    Per sample (``*B`` = ``[N]`` or ``[N, T]``):

    * latent: the squared L2 norm of ``z_tea - z_uni`` (``(*B, Z)``), **summed** over the
      latent dimension, as the paper's ``||.||^2``;
    * goals: SmoothL1 (``beta = smooth_l1_beta``) between ``G_tea`` and ``G_uni``
      (``(*B, N_goals, 2)``, (cos, sin) rows), **averaged** over the last two dimensions;
    * action: SmoothL1 between ``a_tea`` and ``a_uni`` (``(*B, A)``), averaged over joints;
    * privileged latent (not in Eq. 1; weight ``w_priv``, default 0: off): the squared L2 norm
      of ``priv_latent_tea - priv_latent_uni`` (``(*B, P)``), summed like the latent term. RMA's
      adapter regresses the oracle's whole latent, the privileged part included, because the
      frozen oracle actor it feeds reads both.

    Each term is then averaged over the valid samples (``reduction="mean"``): samples whose
    padding mask (key ``mask``, default ``("collector", "mask")``, torchrl's valid-step mask;
    bool ``(*B,)`` or ``(*B, 1)``, ``True`` = valid) is ``False`` contribute nothing; without
    a mask entry every sample counts.

    Teacher tensors are detached: gradients reach the student only. The student action key
    defaults to ``"loc"``, the policy's deterministic mean, so the gradient reaches the policy
    network (a sampled ``"action"`` read from a rollout carries none).

    Student outputs. If ``student_network`` (a TensorDictModule writing ``z_uni``, ``goals_uni``
    and the student action) is given, it is run on every call on a shallow copy of the input,
    so fresh outputs with gradients are used even when the batch holds the (gradient-free)
    values stored by the collector, and the input tensordict is left untouched. Without it,
    the student keys are read from the input: run the student's deterministic forward once
    (``fresh = student_net(td.clone(False))``) and pass ``fresh`` to this loss and to
    :class:`~legoh_rl.objectives.HLMLoss`, which is cheaper when both need the same forward.

    Args:
        student_network: optional TensorDictModule producing the student keys.

    Keyword Args:
        w1, w2, w3: weights of the latent, goal and action terms (paper: 1, 1, 1). A term with
            weight 0 is skipped: its keys are not read and its entries are not written.
        w_priv: weight of the privileged-latent term (default 0: skipped).
        smooth_l1_beta: the SmoothL1 transition point (PyTorch ``beta``; default 1.0).
        reduction: ``"mean"`` (default), ``"sum"`` or ``"none"`` (per-sample ``(*B,)``
            tensors, masked samples zeroed).

    Input keys (``set_keys`` names -> defaults): ``z_tea`` -> ``"z_tea"``, ``z_uni`` ->
    ``"z_uni"``, ``goals_tea`` -> ``"goals_tea"``, ``goals_uni`` -> ``"goals_uni"``,
    ``action_tea`` -> ``"action_tea"``, ``action_uni`` -> ``"loc"``, ``priv_latent_tea`` ->
    ``"priv_latent_tea"``, ``priv_latent_uni`` -> ``"priv_latent_uni"``, ``mask`` ->
    ``("collector", "mask")`` (:data:`~legoh_rl.objectives.VALID_MASK_KEY`, written by torchrl's
    ``split_trajectories`` / ``SliceSampler(pad_output=True)``; e.g. ``set_keys(mask="valid")``
    for another key).

    Returns:
        A TensorDict with ``loss_im_latent`` (``w1 *`` latent term), ``loss_im_goals``,
        ``loss_im_action`` (and ``loss_im_priv_latent`` when ``w_priv > 0``) and the
        unweighted, detached diagnostics ``im_latent``, ``im_goals``, ``im_action``
        (``im_priv_latent``).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys, see the class docstring."""

        z_tea: NestedKey = "z_tea"
        z_uni: NestedKey = "z_uni"
        goals_tea: NestedKey = "goals_tea"
        goals_uni: NestedKey = "goals_uni"
        action_tea: NestedKey = "action_tea"
        action_uni: NestedKey = "loc"
        priv_latent_tea: NestedKey = "priv_latent_tea"
        priv_latent_uni: NestedKey = "priv_latent_uni"
        mask: NestedKey = VALID_MASK_KEY

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    def __init__(
        self,
        student_network: TensorDictModuleBase | None = None,
        *,
        w1: float = 1.0,
        w2: float = 1.0,
        w3: float = 1.0,
        w_priv: float = 0.0,
        smooth_l1_beta: float = 1.0,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        self.student_network = student_network
        self.w1 = check_weight("w1", w1)
        self.w2 = check_weight("w2", w2)
        self.w3 = check_weight("w3", w3)
        self.w_priv = check_weight("w_priv", w_priv)
        if not smooth_l1_beta > 0:
            raise ValueError(f"smooth_l1_beta must be > 0, got {smooth_l1_beta!r}")
        self.smooth_l1_beta = float(smooth_l1_beta)
        self.reduction = check_reduction(reduction)

    @property
    def functional(self) -> bool:
        return False

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator in this loss: nothing to forward (LossModule hook)."""

    def _terms(self) -> list[tuple[str, float, NestedKey, NestedKey]]:
        k = self.tensor_keys
        terms = [
            ("latent", self.w1, k.z_tea, k.z_uni),
            ("goals", self.w2, k.goals_tea, k.goals_uni),
            ("action", self.w3, k.action_tea, k.action_uni),
            ("priv_latent", self.w_priv, k.priv_latent_tea, k.priv_latent_uni),
        ]
        return [t for t in terms if t[1] > 0]

    @property
    def in_keys(self) -> list[NestedKey]:
        keys: list[NestedKey] = []
        for _, _, tea, uni in self._terms():
            keys += [tea, uni]
        return keys + [self.tensor_keys.mask]

    @property
    def out_keys(self) -> list[str]:
        names = [name for name, *_ in self._terms()]
        return [f"loss_im_{n}" for n in names] + [f"im_{n}" for n in names]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Compute L_im on a ``[N]`` or ``[N, T]`` batch; see the class docstring."""
        student = run_student(tensordict, self.student_network)
        out = {}
        for name, weight, tea_key, uni_key in self._terms():
            tea = get_entry(tensordict, tea_key, f"DAggerLoss ({name} term, teacher)").detach()
            uni = get_entry(student, uni_key, f"DAggerLoss ({name} term, student)")
            check_same_shape(f"teacher {tea_key!r}", tea, f"student {uni_key!r}", uni)
            if name in ("latent", "priv_latent"):
                if tea.ndim < 1:
                    raise ValueError(f"latents must have shape (*B, Z), got {tuple(tea.shape)}")
                per_sample = (tea - uni).pow(2).sum(-1)
            elif name == "goals":
                if tea.ndim < 2:
                    raise ValueError(
                        f"goals must have shape (*B, N, 2), got {tuple(tea.shape)}"
                    )
                per_sample = F.smooth_l1_loss(
                    uni, tea, reduction="none", beta=self.smooth_l1_beta
                ).mean((-2, -1))
            else:
                if tea.ndim < 1:
                    raise ValueError(f"actions must have shape (*B, A), got {tuple(tea.shape)}")
                per_sample = F.smooth_l1_loss(
                    uni, tea, reduction="none", beta=self.smooth_l1_beta
                ).mean(-1)
            mask = get_padding_mask(tensordict, self.tensor_keys.mask, per_sample.shape)
            value = reduce_samples(per_sample, mask, self.reduction)
            out[f"loss_im_{name}"] = weight * value
            out[f"im_{name}"] = value.detach()
        return TensorDict(out, batch_size=[])

    def extra_repr(self) -> str:
        return f"w1={self.w1}, w2={self.w2}, w3={self.w3}, w_priv={self.w_priv}, beta={self.smooth_l1_beta}"

