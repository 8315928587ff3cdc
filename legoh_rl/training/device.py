"""The torch device a run computes on, from the recipes' ``device`` setting (one place).

``device`` is ``auto`` (CUDA when ``torch.cuda.is_available()``, else the CPU), ``cpu``, ``cuda``
or ``cuda:<i>``. Every recipe resolves it once, with :func:`resolve_device`, and puts the
networks, losses, GAE, the replay window, the updates and the env's outputs on it (the env's
physics stays on the CPU: MuJoCo; ``HikingEnvConfig.device`` only says where its tensors go).
Checkpoints hold no device: they are loaded to the CPU and moved
(:func:`~legoh_rl.training.checkpoint.load_checkpoint`), so a run trained on a GPU resumes or
evaluates on a CPU and the other way round.
"""

from __future__ import annotations

import re

import torch

__all__ = ["DEVICE_CHOICES", "resolve_device"]

#: what ``device`` may be set to (``cuda:<i>`` for the i-th GPU)
DEVICE_CHOICES = ("auto", "cpu", "cuda", "cuda:<i>")
_CUDA = re.compile(r"cuda(?::(\d+))?")


def resolve_device(name: str | torch.device | None) -> torch.device:
    """The ``torch.device`` a ``device`` setting names.

    Args:
        name: ``"auto"`` (or ``None``): ``cuda`` when ``torch.cuda.is_available()``, else ``cpu``;
            ``"cpu"``; ``"cuda"`` (the current GPU) or ``"cuda:<i>"``; a ``torch.device`` of those.

    Returns:
        the device, with its index for a GPU (``cuda``: the current one, ``cuda:0`` by default), as
        torchrl's envs name theirs.

    Raises:
        ValueError: an unknown value, or a CUDA device this machine does not have (the message
            names the value: ``device=cuda but no CUDA device``).
    """
    text = "auto" if name is None else str(name).strip().lower()
    if text == "auto":
        text = "cuda" if torch.cuda.is_available() else "cpu"
    if text == "cpu":
        return torch.device("cpu")
    match = _CUDA.fullmatch(text)
    if match is None:
        raise ValueError(f"device={name!r} is not a device: use one of {list(DEVICE_CHOICES)}")
    if not torch.cuda.is_available():
        raise ValueError(f"device={name} but no CUDA device: torch {torch.__version__} sees no GPU "
                         "(a CPU-only build, or no driver); use device=cpu or device=auto")
    index = torch.cuda.current_device() if match.group(1) is None else int(match.group(1))
    if index >= torch.cuda.device_count():
        raise ValueError(f"device={name} but this machine has {torch.cuda.device_count()} CUDA device(s) "
                         f"(cuda:0 .. cuda:{torch.cuda.device_count() - 1})")
    return torch.device("cuda", index)
