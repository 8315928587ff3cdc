"""Load a policy checkpoint (oracle, student, or the zero-action baseline) with its eval env.

Checkpoints load to the CPU (:func:`~legoh_rl.training.checkpoint.load_checkpoint`) whatever
device they were trained on; ``device`` moves the policy there and has the env deliver its
tensors there.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from legoh_rl.modules.oracle import make_oracle_actor
from legoh_rl.training.builders import eval_env, oracle_networks, policy_env_kwargs, policy_meta
from legoh_rl.training.checkpoint import check_meta, load_checkpoint
from legoh_rl.training.evaluation import EvalProtocol
from legoh_rl.training.onnx_policy import load_onnx_policy
from legoh_rl.training.student import locomotion_network, make_student, student_env

__all__ = ["ZeroPolicy", "load_policy", "load_cell_policy", "load_student"]


class ZeroPolicy(TensorDictModuleBase):
    """Action 0 for every world: the PD hold at the default pose (a no-policy baseline)."""

    def __init__(self, num_actions: int) -> None:
        super().__init__()
        self.num_actions = num_actions
        self.in_keys = []
        self.out_keys = ["action"]

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        td.set("action", torch.zeros(*td.batch_size, self.num_actions, device=td.device))
        return td


def load_student(state: dict, protocol, variants: int, seed: int, num_threads=None, trails=None, path: str = "checkpoint",
                 device: torch.device | str = "cpu", physics: str = "mujoco", domain_rand: bool | tuple[str, ...] = False):
    """``(env, policy, kind)`` to evaluate a ``unified.py`` checkpoint on ``protocol`` (on ``device``,
    the worlds stepped by ``physics``, randomised when ``domain_rand``: :func:`eval_env`)."""
    meta = state["meta"]
    blind = "depth" not in meta["obs_layout"]  # RMA-B: trained without the camera, evaluated without it
    base = eval_env(meta["robot"], protocol, variants, seed, num_threads, depth=not blind, trails=trails, device=device,
                    physics=physics, domain_rand=domain_rand, **policy_env_kwargs(meta))
    check_meta(meta, {**policy_meta(base, "student"), "perception": meta["perception"], "preset": meta["preset"]}, path)
    student = make_student(base, meta["perception"], meta["preset"], oracle_config=meta.get("oracle_config"),
                           network=locomotion_network(meta))
    student.perception.load_state_dict(state["perception"])
    student.actor.load_state_dict(state["actor"])
    student.policy.to(device)
    return student_env(base, student), student.policy, f"student ({meta['perception']})"


def load_policy(checkpoint: str, protocol, robot: str = "h1", variants: int = 2, seed: int = 0,
                num_threads=None, trails=None, device: torch.device | str = "cpu", physics: str = "mujoco",
                domain_rand: bool | tuple[str, ...] = False):
    """``(env, policy, kind)`` for a checkpoint path, or ``"zero"`` for the PD-hold baseline, the
    policy and the env's tensors on ``device``, the worlds stepped by ``physics`` (``mujoco`` |
    ``warp``, docs/gpu_physics.md), with the training's randomisation when ``domain_rand``
    (:func:`eval_env`).

    A path ending in ``.onnx`` names exported graphs, run with onnxruntime
    (:func:`~legoh_rl.training.onnx_policy.load_onnx_policy`) on the CPU, with the env on the CPU
    whatever ``device`` says.

    Raises:
        FileNotFoundError: no checkpoint at the path.
        ValueError: the checkpoint's kind is unknown, or it was made for another robot or
            observation layout than its eval env.
    """
    if checkpoint == "zero":
        env = eval_env(robot, protocol, variants, seed, num_threads, trails=trails, device=device, physics=physics,
                       domain_rand=domain_rand)
        return env, ZeroPolicy(env.A), "zero-action"
    if str(checkpoint).endswith(".onnx"):  # graphs from export_policy.py --format onnx
        return load_onnx_policy(checkpoint, protocol, variants, seed, num_threads, trails=trails, physics=physics,
                                domain_rand=domain_rand)
    state = load_checkpoint(checkpoint)
    meta = state.get("meta", {})
    kind = meta.get("kind")
    if kind == "oracle":
        env = eval_env(meta["robot"], protocol, variants, seed, num_threads, trails=trails, device=device,
                       physics=physics, domain_rand=domain_rand, **policy_env_kwargs(meta))
        check_meta(meta, policy_meta(env, "oracle"), checkpoint)
        return env, make_oracle_actor(oracle_networks(state).to(device)), "oracle"
    if kind == "student":
        return load_student(state, protocol, variants, seed, num_threads, trails=trails, path=checkpoint, device=device,
                            physics=physics, domain_rand=domain_rand)
    raise ValueError(f"{checkpoint}: unknown checkpoint kind {kind!r}; expected 'oracle' or 'student'")


def load_cell_policy(checkpoint: str, category: str, level: int, robots: int, seed: int = 0, variants: int = 2):
    """``(env, policy, kind, base)`` for ``robots`` worlds on one (category, level) cell, physics on
    one thread: what the probe recipes (``gait_stats.py``, ``route_following.py``) roll out.
    ``base`` is the untransformed :class:`HikingEnv` (``env`` itself for an oracle)."""
    protocol = EvalProtocol(categories=(category,), levels=(level,), robots_per_cell=robots, seed=seed)
    env, policy, kind = load_policy(checkpoint, protocol, variants=variants, seed=seed, num_threads=1)
    return env, policy, kind, getattr(env, "base_env", env)
