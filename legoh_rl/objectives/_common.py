"""Helpers shared by the LEGO-H loss modules (reduction with a padding mask, checks)."""

from __future__ import annotations

import math

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor

_REDUCTIONS = ("mean", "sum", "none")

#: The valid-step (padding) mask every LEGO-H loss reads by default: torchrl's own key, written
#: by ``split_trajectories``, ``SliceSampler(pad_output=True)`` and the collectors' padded
#: trajectory batches (bool ``(*B,)`` or ``(*B, 1)``, ``True`` = valid), and the one
#: ``ClipPPOLoss`` (``loss_mask_key="auto"``) and :func:`~legoh_rl.objectives.policy_kl` read.
#: A batch without it counts every step. See docs/keys.md.
VALID_MASK_KEY: tuple[str, str] = ("collector", "mask")


def check_weight(name: str, value: float) -> float:
    """Return ``value`` as a float, raising if it is not a finite number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a float, got {value!r}")
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


def check_reduction(reduction: str) -> str:
    if reduction not in _REDUCTIONS:
        raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")
    return reduction


def check_same_shape(name_a: str, a: Tensor, name_b: str, b: Tensor) -> None:
    if a.shape != b.shape:
        raise ValueError(
            f"{name_a} and {name_b} must have the same shape, got {tuple(a.shape)} and "
            f"{tuple(b.shape)}"
        )


def get_entry(tensordict: TensorDictBase, key: NestedKey, what: str) -> Tensor:
    value = tensordict.get(key, None)
    if value is None:
        raise KeyError(
            f"{what}: key {key!r} not found in the input tensordict (keys: "
            f"{sorted(map(str, tensordict.keys(True, True)))}). Use set_keys(...) to remap it."
        )
    return value


def get_padding_mask(
    tensordict: TensorDictBase, key: NestedKey | None, sample_shape: torch.Size
) -> Tensor | None:
    """Read the bool padding mask (``True`` = valid) at ``key``, shaped like the per-sample loss.

    ``key`` is the loss's ``mask`` key, :data:`VALID_MASK_KEY` unless remapped.

    A trailing singleton dimension (``(*B, 1)``) is dropped. Returns ``None`` when ``key`` is
    ``None`` or absent from ``tensordict`` (every element counts).
    """
    if key is None:
        return None
    mask = tensordict.get(key, None)
    if mask is None:
        return None
    if mask.dtype != torch.bool:
        raise TypeError(f"padding mask {key!r} must be a bool tensor, got dtype {mask.dtype}")
    while mask.ndim > len(sample_shape) and mask.shape[-1] == 1:
        mask = mask.squeeze(-1)
    if mask.shape != sample_shape:
        raise ValueError(
            f"padding mask {key!r} of shape {tuple(mask.shape)} does not match the batch shape "
            f"{tuple(sample_shape)} of the per-sample loss"
        )
    return mask


def reduce_samples(values: Tensor, mask: Tensor | None, reduction: str) -> Tensor:
    """Reduce a per-sample loss ``(*B,)`` over the valid (mask ``True``) samples.

    ``"mean"``: sum over valid samples / number of valid samples (0 if none is valid);
    ``"sum"``: sum over valid samples; ``"none"``: the per-sample tensor, masked samples zeroed.
    Masked samples are *selected out* (``torch.where``): their values never reach the result.
    """
    if mask is not None:
        values = torch.where(mask, values, torch.zeros_like(values))
    if reduction == "none":
        return values
    if reduction == "sum":
        return values.sum()
    count = values.numel() if mask is None else mask.sum()
    if mask is None:
        return values.mean() if count > 0 else values.sum()
    return values.sum() / count.clamp_min(1)


def run_student(
    tensordict: TensorDictBase, student_network: TensorDictModuleBase | None
) -> TensorDictBase:
    """Return the tensordict the student keys are read from.

    Without a ``student_network`` this is the input itself. With one, the network is run on a
    shallow copy (``clone(False)``), so the caller's tensordict is left untouched and the outputs
    carry gradients for this loss.
    """
    if student_network is None:
        return tensordict
    return student_network(tensordict.clone(False))


class SeededGenerators:
    """One ``torch.Generator`` per device, each seeded with the same ``seed`` on first use.

    ``seed=None`` draws the seed from torch's global RNG at construction, so
    ``torch.manual_seed`` before building a loss makes its masks and samples reproducible.
    """

    def __init__(self, seed: int | None = None) -> None:
        if seed is None:
            seed = int(torch.randint(0, 2**62, (1,)).item())
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise TypeError(f"seed must be an int or None, got {seed!r}")
        self.seed = seed
        self._generators: dict[torch.device, torch.Generator] = {}

    def get(self, device: torch.device | str) -> torch.Generator:
        device = torch.device(device)
        gen = self._generators.get(device)
        if gen is None:
            gen = torch.Generator(device=device)
            gen.manual_seed(self.seed)
            self._generators[device] = gen
        return gen

    def reset(self) -> None:
        """Forget the generators: the next draws restart from ``seed``."""
        self._generators.clear()
