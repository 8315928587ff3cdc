"""Atomic, resumable checkpoints.

A checkpoint is one ``torch.save`` file holding everything a run needs to continue: model and
optimiser states, schedulers, env state (curriculum, rng, counters), torch and numpy RNG states,
the iteration and frame counters, the logger's run id, and a ``meta`` block (robot, observation
layout, action size, kind of policy) that loaders check before using it.

Writes go to a temporary file in the same folder, are flushed to disk, then renamed over the
target: a run killed while writing leaves the previous checkpoint intact.
"""

from __future__ import annotations

import hashlib
import os
import random
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

__all__ = [
    "save_checkpoint", "load_checkpoint", "check_meta", "rng_state", "set_rng_state", "resume_path", "export_policy",
    "CheckpointError", "require_training_state", "load_weights", "file_digest",
]


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file, hex (identifies a checkpoint: a student's teacher, a branch point, an
    evaluated policy)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class CheckpointError(ValueError):
    """A file that is not a usable checkpoint for what was asked (the message names the file)."""


def rng_state() -> dict:
    """Torch, numpy-global and python RNG states, and the CUDA generators' (``"cuda"``, one per GPU)
    when CUDA is in use: a run on a GPU samples its actions there."""
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    """Restore :func:`rng_state`; the CUDA states only where this machine has as many GPUs (a GPU
    run resumed on a CPU goes on with the CPU generators alone)."""
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    cuda = state.get("cuda")
    if cuda is not None and torch.cuda.is_available() and torch.cuda.device_count() == len(cuda):
        torch.cuda.set_rng_state_all(cuda)


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` atomically (temp file + fsync + rename); return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; a checkpoint is an ordinary shareable file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint`.

    Every tensor is loaded to the CPU (``map_location="cpu"``), wherever it was saved from: a
    checkpoint of a GPU run loads on a machine without one, and the recipes move what they load
    to their ``device`` (``load_state_dict`` into modules already there; optimisers cast their state
    to their parameters' device).

    Raises:
        FileNotFoundError: no file at ``path`` (the message names it).
        CheckpointError: the file is empty, truncated or not a checkpoint (names it).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # EOFError, UnpicklingError, zip errors, ...: all mean the same to a user
        size = path.stat().st_size
        raise CheckpointError(f"{path} ({size} bytes) is not a readable checkpoint ({type(err).__name__}: {err}); "
                              "it may be empty or cut short: point to another file, or delete it") from None
    if not isinstance(state, dict) or "meta" not in state:
        raise CheckpointError(f"{path} is not a legoh-rl checkpoint (no 'meta' block)")
    return state


def require_training_state(state: dict, path: str | os.PathLike, keys: tuple[str, ...]) -> None:
    """Refuse to resume from a file without the training state ``keys`` (a slim policy export).

    Raises:
        CheckpointError: names the file, the missing keys and what to use instead.
    """
    missing = [k for k in keys if k not in state]
    if missing:
        raise CheckpointError(f"{path} holds no training state (missing {missing}): it is a policy export, which "
                              "cannot be resumed. Resume from a run's last.pt, or start a new run from its weights "
                              f"with checkpoint.init={path}")


def load_weights(module: torch.nn.Module, weights: dict, path: str | os.PathLike, what: str, hint: str) -> None:
    """``module.load_state_dict(weights)`` with an error that names the file and the config to fix.

    Raises:
        CheckpointError: the shapes or names differ (``what`` names the part, ``hint`` the setting).
    """
    own = module.state_dict()
    bad = [f"{k}: checkpoint {tuple(v.shape)}, this run {tuple(own[k].shape)}" for k, v in weights.items()
           if k in own and torch.is_tensor(v) and tuple(v.shape) != tuple(own[k].shape)]
    missing = sorted(set(own) - set(weights))
    unexpected = sorted(set(weights) - set(own))
    if bad or missing or unexpected:
        parts = ([f"size mismatch {'; '.join(bad[:2])}"] if bad else []) + (
            [f"missing {missing[:3]}"] if missing else []) + ([f"unexpected {unexpected[:3]}"] if unexpected else [])
        raise CheckpointError(f"{path}: its {what} do not fit this run's ({'; '.join(parts)}); {hint}")
    module.load_state_dict(weights)


def check_meta(meta: dict, expected: dict, path: str | os.PathLike = "checkpoint") -> None:
    """Refuse a checkpoint made for another robot, observation layout or policy kind.

    Raises:
        ValueError: naming each mismatching field with both values.
    """
    bad = [f"{k}: checkpoint has {meta.get(k)!r}, this run needs {v!r}" for k, v in expected.items() if meta.get(k) != v]
    if bad:
        raise ValueError(f"{path} does not fit this run: " + "; ".join(bad))


def resume_path(resume: str | None, run_dir: str | os.PathLike) -> Path | None:
    """The checkpoint a run continues from: ``None`` (fresh run), ``"auto"`` (``run_dir/last.pt``
    if it exists) or a path, which must exist.

    Raises:
        FileNotFoundError: an explicit path with no checkpoint (the message names it).
    """
    if resume is None:
        return None
    if resume == "auto":
        last = Path(run_dir) / "last.pt"
        return last if last.is_file() else None
    if not Path(resume).is_file():
        raise FileNotFoundError(f"checkpoint.resume: no checkpoint at {resume}")
    return Path(resume)


#: what a policy needs for inference (evaluate.py, the unified recipe's teacher)
POLICY_KEYS = ("meta", "oracle_config", "networks", "perception", "actor", "config", "iteration", "frames")


def export_policy(src: str | os.PathLike, dst: str | os.PathLike, provenance: dict | None = None) -> Path:
    """Write a slim copy of a training checkpoint: the policy without optimisers, env or RNG state.

    The result loads wherever the full checkpoint does for inference (``evaluate.py``, or as the
    teacher of ``unified.py``), and is small enough to commit. ``provenance`` (``experiment``,
    ``stage``) is written into its meta block, for checkpoints trained before runs recorded it.
    """
    state = load_checkpoint(src)
    slim = {k: state[k] for k in POLICY_KEYS if k in state}
    if provenance:
        slim["meta"] = {**slim.get("meta", {}), **provenance}
    return save_checkpoint(dst, slim)
