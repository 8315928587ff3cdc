"""One control step of a :class:`~legoh_rl.envs.hiking.HikingEnv` that restarts finished worlds.

The Gymnasium vector env (:class:`~legoh_rl.envs.gym_env.HikingVectorEnv`) and the rsl_rl
adapter (:class:`~legoh_rl.envs.rsl_rl_env.HikingRslRlEnv`) drive the batched env through
:func:`step_autoreset`: the step of all N worlds, then one partial reset of the worlds whose
episode ended at that step (the same two calls torchrl's ``step_and_maybe_reset`` makes, without
its ``step_mdp`` bookkeeping). The observations handed on are the reset worlds' first ones and
the other worlds' next ones; the step's own output keeps the ended worlds' last observations.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from legoh_rl.envs.hiking import HikingEnv

__all__ = ["step_autoreset", "reset_worlds"]


def step_autoreset(env: HikingEnv, action: torch.Tensor) -> tuple[TensorDictBase, TensorDictBase, torch.Tensor]:
    """Step all worlds, then reset the worlds whose episode ended.

    Args:
        env: the batched env (N worlds, A actions).
        action: (N, A) floating-point actions (any device; moved to ``env.device``).

    Returns:
        ``(step, obs, done)``: ``step`` is the step's output (the env's ``"next"`` entries:
        observations before any reset, ``reward`` (N, 1), ``terminated``/``truncated``/``done``
        (N, 1), ``reward_terms``, ``episode``); ``obs`` holds the observations to act on next
        (batch [N]): the reset output when some world ended (its other rows are the step's
        observations, unchanged), else ``step`` itself; ``done`` is the (N,) bool mask of the
        worlds that ended (and were reset).

    Raises:
        ValueError: ``action`` is not (N, A).
    """
    n, a = env.batch_size[0], env.A
    if tuple(action.shape) != (n, a):
        raise ValueError(f"actions must have shape {(n, a)} (num_envs, num_actions), got {tuple(action.shape)}")
    td = TensorDict({"action": action.to(env.device)}, batch_size=env.batch_size, device=env.device)
    step = env.step(td).get("next")
    done = step.get("done").reshape(n)
    if bool(done.any()):
        return step, reset_worlds(env, done), done
    return step, step, done


def reset_worlds(env: HikingEnv, mask: torch.Tensor) -> TensorDictBase:
    """Reset the worlds of an (N,) bool ``mask`` (a partial reset; all N rows come back: the
    others' observations unchanged, done flags False).

    Raises:
        ValueError: ``mask`` is not (N,) bool.
    """
    n = env.batch_size[0]
    if mask.dtype != torch.bool or tuple(mask.shape) != (n,):
        raise ValueError(f"a reset mask must be a ({n},) bool tensor, got {tuple(mask.shape)} {mask.dtype}")
    td = TensorDict({"_reset": mask.reshape(n, 1).to(env.device)}, batch_size=env.batch_size, device=env.device)
    # HikingEnv._reset itself: its output holds every row (the others' last observations, kept by
    # the env). torchrl's public reset would merge it into the input tensordict, keeping the input's
    # rows outside the mask: zeros here, as this input has no observations.
    return env._reset(td)
