"""An exponential moving average of a policy's weights, for its snapshots (``checkpoint.ema_decay``).

A student's snapshots taken a few hundred iterations apart swing by several points on the
benchmark (Forest 83 -> 42 -> 78 in ``runs/student_h1``): each is the weights after one noisy
optimiser step. Evaluating an average of the recent weights (Polyak averaging) instead smooths
that noise at no cost to training: the average only reads the trained parameters, draws no random
numbers, and the optimiser never sees it, so a run with it trains bit for bit as one without.

The average is torch's :class:`~torch.optim.swa_utils.AveragedModel` with its EMA rule, over the
named networks of a policy checkpoint (``{"perception": ..., "actor": ...}`` for a student,
:data:`~legoh_rl.training.checkpoint.POLICY_KEYS`), buffers included. The runner updates it after
every iteration and writes, beside each raw snapshot, ``snapshots/ema/frames<N>.pt``: the same
slim checkpoint with the averaged weights, loadable wherever the raw one is.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

__all__ = ["PolicyAverage", "saved_average"]


class PolicyAverage:
    """The EMA ``w_avg <- decay * w_avg + (1 - decay) * w`` of some named networks, once per call
    of :meth:`update` (one training iteration).

    Args:
        networks: ``{checkpoint key: module}``, e.g. ``{"perception": tcvit, "actor": locomotion}``;
            the averaged state dicts come back under the same keys with the modules' own names.
        decay: the EMA's decay in (0, 1); its horizon is about ``1 / (1 - decay)`` iterations.

    Raises:
        ValueError: ``decay`` outside (0, 1), or no networks.
    """

    def __init__(self, networks: Mapping[str, nn.Module], decay: float) -> None:
        if isinstance(decay, bool) or not isinstance(decay, (int, float)) or not 0.0 < float(decay) < 1.0:
            raise ValueError(f"checkpoint.ema_decay must be a number in (0, 1) (null: no average), got {decay!r}")
        if not networks:
            raise ValueError("PolicyAverage needs at least one network to average")
        self.decay = float(decay)
        self.networks = nn.ModuleDict(dict(networks))
        # use_buffers: normalisation statistics are averaged too, so the copy is self-consistent
        self.average = AveragedModel(self.networks, multi_avg_fn=get_ema_multi_avg_fn(self.decay), use_buffers=True)

    @torch.no_grad()
    def update(self) -> None:
        """Fold the networks' current weights into the average (the first call copies them)."""
        self.average.update_parameters(self.networks)

    @property
    def count(self) -> int:
        """How many updates the average has seen."""
        return int(self.average.n_averaged)

    def policy_state(self) -> dict[str, dict[str, torch.Tensor]]:
        """``{checkpoint key: state dict}`` of the averaged networks (the raw weights before the
        first :meth:`update`), in the layout the checkpoint's raw entries have."""
        if self.count == 0:
            return {k: m.state_dict() for k, m in self.networks.items()}
        return {k: m.state_dict() for k, m in self.average.module.items()}

    def state_dict(self) -> dict:
        """What a resume needs: the averaged weights, the update count and the decay."""
        return {"decay": self.decay, "state": self.average.state_dict()}

    def load_state_dict(self, state: Mapping) -> None:
        """Continue an average saved by :meth:`state_dict`.

        Raises:
            ValueError: it was taken with another decay (the switch changed between runs).
        """
        if float(state["decay"]) != self.decay:
            raise ValueError(f"the checkpoint's weight average has decay {state['decay']}, this run's "
                             f"checkpoint.ema_decay is {self.decay}: resume with the same value")
        self.average.load_state_dict(state["state"])


def saved_average(state: Mapping) -> dict[str, dict[str, torch.Tensor]] | None:
    """The averaged weights a training checkpoint holds (``state["weight_average"]``, written from
    :meth:`PolicyAverage.state_dict`), as ``{checkpoint key: state dict}`` like
    :meth:`PolicyAverage.policy_state`; ``None`` when the run kept no average or it saw no update.

    No networks are built: the ``module.<key>.<name>`` entries of the averaged model are split by key.
    """
    saved = state.get("weight_average")
    if not saved or int(saved["state"].get("n_averaged", 0)) == 0:
        return None
    out: dict[str, dict[str, torch.Tensor]] = {}
    for name, value in saved["state"].items():
        if name == "n_averaged":
            continue
        key, _, rest = name.removeprefix("module.").partition(".")
        out.setdefault(key, {})[rest] = value
    return out
