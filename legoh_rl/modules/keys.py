"""Default TensorDict keys of the networks (see ``docs/keys.md`` for the contract).

Each builder takes one of these dataclasses, so a project with other key names can rename
any input or output without touching the networks: e.g.
``PerceptionKeys(depth_goal_stack=("obs", "depth_goal"))``.
"""

from __future__ import annotations

from dataclasses import dataclass

NestedKey = str | tuple  # a TensorDict key: a string or a tuple of strings

__all__ = [
    "AdaptationKeys",
    "LocomotionKeys",
    "NestedKey",
    "OracleKeys",
    "PerceptionKeys",
]


@dataclass(frozen=True)
class PerceptionKeys:
    """Keys read and written by the perception networks (TC-ViT and its baselines).

    Inputs (shapes without the batch): ``depth_goal_stack`` (T, 1+G, H, W), ``depth``
    (1, H, W), ``goal_gps`` (2,), ``waypoint_gps`` (2,), ``proprio`` (D,),
    ``proprio_history`` (T_h, D), ``is_init`` (1,) bool. Outputs: ``z_uni`` (latent,),
    ``delta_g0`` (2,), ``goals_uni`` (N, 2); the RMA adapters also ``priv_latent_uni``
    (priv_latent,), their estimate of the oracle's privileged latent. The remaining keys are intermediate features
    and recurrent state (``hidden`` for GRUs; ``context`` / ``context_valid`` for the causal
    transformer's rolling window).
    """

    depth_goal_stack: NestedKey = "depth_goal_stack"
    depth: NestedKey = "depth"
    goal_gps: NestedKey = "goal_gps"
    waypoint_gps: NestedKey = "waypoint_gps"
    proprio: NestedKey = "proprio"
    proprio_history: NestedKey = "proprio_history"
    is_init: NestedKey = "is_init"
    z_uni: NestedKey = "z_uni"
    delta_g0: NestedKey = "delta_g0"
    goals_uni: NestedKey = "goals_uni"
    features: NestedKey = "perception_features"
    memory_in: NestedKey = "perception_memory_in"
    memory_out: NestedKey = "perception_memory_out"
    hidden: NestedKey = "perception_hidden"
    context: NestedKey = "perception_context"
    context_valid: NestedKey = "perception_context_valid"
    priv_latent_uni: NestedKey = "priv_latent_uni"


@dataclass(frozen=True)
class OracleKeys:
    """Keys of the oracle actor-critic.

    Inputs: ``proprio`` (D,), ``scandots`` (132,), ``privileged`` (P,), ``expert_goals``
    (N, 2). Outputs: ``z_tea`` (32,), ``priv_latent`` (20,), ``loc``/``scale`` (A,),
    ``action`` (A,), ``action_log_prob`` (), ``state_value`` (1,).
    """

    proprio: NestedKey = "proprio"
    scandots: NestedKey = "scandots"
    privileged: NestedKey = "privileged"
    expert_goals: NestedKey = "expert_goals"
    z_tea: NestedKey = "z_tea"
    priv_latent: NestedKey = "priv_latent"
    loc: NestedKey = "loc"
    scale: NestedKey = "scale"
    action: NestedKey = "action"
    state_value: NestedKey = "state_value"


@dataclass(frozen=True)
class LocomotionKeys:
    """Keys of the student locomotion actor.

    Inputs: ``z_uni`` (latent,), ``proprio`` (D,), ``delta_g0`` (2,), ``goal_next`` (2,); the
    frozen oracle's actor (RMA) reads ``proprio``, ``z_uni``, ``priv_latent_uni`` (20,) and
    ``goals_uni`` (N, 2) instead. Outputs: ``loc``/``scale`` (A,), ``action`` (A,), ``action_log_prob`` ().
    """

    z_uni: NestedKey = "z_uni"
    proprio: NestedKey = "proprio"
    delta_g0: NestedKey = "delta_g0"
    goal_next: NestedKey = "goal_next"
    priv_latent_uni: NestedKey = "priv_latent_uni"
    goals_uni: NestedKey = "goals_uni"
    loc: NestedKey = "loc"
    scale: NestedKey = "scale"
    action: NestedKey = "action"


@dataclass(frozen=True)
class AdaptationKeys:
    """Keys of the adaptation module: ``proprio_history`` (T_h, D) -> ``priv_latent_hat``."""

    proprio_history: NestedKey = "proprio_history"
    priv_latent: NestedKey = "priv_latent_hat"
