"""Videos of a policy file during training: a few robots on the run's trail categories.

The training env holds hundreds of worlds stepping under a sampling policy; a video instead
loads the checkpoint just written into a small eval env (deterministic actions, no
randomisation) with one robot per category, as ``recipes/evaluate.py`` does, so oracle and
student runs get the same kind of video.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from legoh_rl.training.evaluation import EvalProtocol, render_video
from legoh_rl.training.policies import load_policy

__all__ = ["policy_video"]


def policy_video(checkpoint: str | Path, path: str | Path, categories: Sequence[str], level: int,
                 seconds: float = 4.0, seed: int = 0, num_threads: int | None = 1) -> Path | None:
    """Render ``checkpoint``'s policy on one trail of each of the first four ``categories`` at ``level``.

    Args:
        checkpoint: a ``last.pt`` or a slim policy file (oracle or student).
        path: the .mp4 to write (its folder is created).
        categories: trail categories (the run's ``env.categories``); one robot on each of the
            first four, tiled two per row.
        level: the trail level (0-4) of every robot.
        seconds: simulated seconds (25 frames per second).
        seed: trail grid seed; ``num_threads``: physics threads of the small eval env.

    Returns:
        the path, or None (with a warning) when this machine cannot render (no OpenGL context).
    """
    cats = tuple(categories)[:4]
    protocol = EvalProtocol(categories=cats, levels=(int(level),), robots_per_cell=1, trajectories=0)
    env, policy, _ = load_policy(str(checkpoint), protocol, variants=1, seed=seed, num_threads=num_threads)
    base = getattr(env, "base_env", env)
    index = {name: i for i, name in enumerate(base.trails.categories)}
    base.assign_tiles(np.full(len(cats), int(level)), np.array([index[c] for c in cats]))
    try:
        return render_video(env, policy, path, worlds=len(cats), seconds=seconds)
    finally:
        base.close()
