"""Builders for the unified (student) policy: the transformed env and TC-ViT + locomotion.

The student acts at 50 Hz but perceives at 10 Hz:

* env side: ``InitTracker`` (``is_init``), ``DepthHistory`` (16 frames -> 4, on ticks),
  ``GoalTiling`` (P_B as a plane per frame), and the primers that carry the perception module's
  recurrent state and :class:`~legoh_rl.transforms.PerceptionHold`'s held outputs;
* policy side: ``PerceptionHold(perception)`` (one perception forward per tick, latent tiling,
  nearest-goal forwarding) followed by the locomotion actor.
"""

from __future__ import annotations

import warnings

from tensordict.nn import TensorDictSequential
from torchrl.envs import CatFrames, Compose, InitTracker, TransformedEnv, UnsqueezeTransform
from torchrl.modules.utils import get_primers_from_module

from legoh_rl.envs import HikingEnv
from legoh_rl.modules.configs import LocomotionConfig, perception_config
from legoh_rl.modules.locomotion import make_locomotion_actor
from legoh_rl.modules.perception import make_perception
from legoh_rl.transforms import DepthHistory, GoalTiling, PerceptionHold

__all__ = ["StudentPolicy", "make_student", "student_env"]


class StudentPolicy:
    """The student's parts: ``perception``, ``hold`` (PerceptionHold around it), ``actor``
    (locomotion ProbabilisticActor) and ``policy`` = hold then actor (what the Collector runs)."""

    def __init__(self, perception, hold: PerceptionHold, actor, history_len: int = 10) -> None:
        self.perception = perception
        self.history_len = history_len
        self.hold = hold
        self.actor = actor
        self.policy = TensorDictSequential(hold, actor)


def make_student(env: HikingEnv, perception: str = "tcvit", preset: str = "cpu",
                 init_std: float = 1.0) -> StudentPolicy:
    """Build the student sized for ``env`` (student or eval mode, depth on).

    Args:
        env: the (untransformed) hiking env.
        perception: a name of :func:`legoh_rl.modules.perception.make_perception`
            (``tcvit``, ``tcvit_ct``, ``vanilla``, ``eph``, ``rmah``, ``rmab``).
        preset: ``"cpu"`` (64x64) or ``"paper"`` (128x128); must match the env's depth size.
        init_std: initial action std of the locomotion actor (the unified recipe passes its
            teacher's).
    """
    if not env.cfg.depth_enabled:
        raise ValueError("the student needs the depth camera: build the env in 'student' or 'eval' mode")
    spec = env.observation_spec
    proprio_dim = spec["proprio"].shape[-1]
    size = spec["depth"].shape[-1]
    pcfg = perception_config(preset, proprio_dim, image_size=size, num_goals=spec["expert_goals"].shape[-2])
    perc = make_perception(perception, pcfg)
    hold = PerceptionHold(perc)
    actor = make_locomotion_actor(LocomotionConfig(proprio_dim=proprio_dim, num_actions=env.A, init_std=init_std))
    return StudentPolicy(perc, hold, actor, pcfg.io.history_len)


def student_env(env: HikingEnv, student: StudentPolicy) -> TransformedEnv:
    """Wrap ``env`` with the student's transforms and state primers."""
    transforms = [InitTracker(), DepthHistory(), GoalTiling()]
    if "proprio_history" in student.perception.in_keys:  # RMA baselines: (T_h, D) proprio history
        transforms += [
            UnsqueezeTransform(dim=-2, in_keys=["proprio"], out_keys=["proprio_frame"]),
            CatFrames(N=student.history_len, dim=-2, in_keys=["proprio_frame"], out_keys=["proprio_history"]),
        ]
    with warnings.catch_warnings():  # stateless perception (no primer) is fine
        warnings.filterwarnings("ignore", message="No primers found")
        primers = get_primers_from_module(student.perception)
    if primers is not None:
        transforms.append(primers)
    transforms.append(student.hold.make_tensordict_primer())
    return TransformedEnv(env, Compose(*transforms))
