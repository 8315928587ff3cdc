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
from collections.abc import Mapping

from tensordict.nn import TensorDictSequential
from torchrl.envs import CatFrames, Compose, InitTracker, TransformedEnv, UnsqueezeTransform
from torchrl.modules.utils import get_primers_from_module

from legoh_rl.envs import HikingEnv
from legoh_rl.modules.configs import LocomotionConfig, OracleConfig, perception_config
from legoh_rl.modules.keys import PerceptionKeys
from legoh_rl.modules.locomotion import make_locomotion_actor, make_oracle_locomotion_actor
from legoh_rl.modules.oracle import oracle_network_class
from legoh_rl.modules.perception import make_perception
from legoh_rl.transforms import DepthHistory, GoalTiling, PerceptionHold

__all__ = ["LOCOMOTIONS", "StudentPolicy", "locomotion_network", "make_student", "student_env", "student_networks"]

#: the student's locomotion module: its own network (``student.network``, a name in
#: ``LOCOMOTION_NETWORKS``) trained by the recipe (``learned``, LEGO-H), or
#: the teacher's actor, frozen, fed the perception's estimates of its latents (``oracle``, RMA)
LOCOMOTIONS = ("learned", "oracle")
#: the perception outputs the frozen oracle actor reads
ORACLE_LOCOMOTION_INPUTS = ("z_uni", "priv_latent_uni", "goals_uni")


def locomotion_network(meta: Mapping) -> str:
    """The learned locomotion network a student checkpoint's ``meta`` block names
    (``meta["locomotion_network"]``, the recipe's ``student.network``); a block that names none
    holds the default, ``LocomotionConfig.network`` (``"mlp"``)."""
    return str(meta.get("locomotion_network", LocomotionConfig.network))


class StudentPolicy:
    """The student's parts: ``perception``, ``hold`` (PerceptionHold around it), ``actor``
    (locomotion ProbabilisticActor) and ``policy`` = hold then actor (what the Collector runs)."""

    def __init__(self, perception, hold: PerceptionHold, actor, history_len: int = 10) -> None:
        self.perception = perception
        self.history_len = history_len
        self.hold = hold
        self.actor = actor
        self.policy = TensorDictSequential(hold, actor)


def student_networks(perception: str, preset: str, proprio_dim: int, image_size: int | None, num_goals: int,
                     num_actions: int, init_std: float = 1.0, oracle_config: Mapping | None = None,
                     network: str = LocomotionConfig.network):
    """``(perception, locomotion actor, perception config)`` of a student, untrained.

    Args:
        perception: a name of :func:`legoh_rl.modules.perception.make_perception`.
        preset: ``"cpu"`` (64x64) or ``"paper"`` (128x128).
        proprio_dim, image_size, num_goals, num_actions: the env's sizes (D, H = W, N, A);
            ``image_size`` ``None``: the preset's (a student without depth).
        init_std: initial action std of a learned locomotion actor.
        oracle_config: ``None`` for the student's own locomotion MLP (``learned``); an oracle's
            :class:`~legoh_rl.modules.configs.OracleConfig` fields for its actor, frozen
            (``oracle``, RMA), whose weights the caller loads. It needs a perception that
            estimates the privileged latent (``rmah``, ``rmab``).
        network: the learned locomotion's class, a name in
            :data:`~legoh_rl.modules.locomotion.LOCOMOTION_NETWORKS` (unused with ``oracle_config``).

    Raises:
        ValueError: an unregistered ``network`` (the message lists the registered ones);
            ``oracle_config`` with a perception that does not write ``priv_latent_uni``, or an
            oracle whose sizes differ from the student's.
    """
    sizes = {"num_goals": num_goals} | ({} if image_size is None else {"image_size": image_size})
    pcfg = perception_config(preset, proprio_dim, **sizes)
    perc = make_perception(perception, pcfg)
    if oracle_config is None:
        actor = make_locomotion_actor(LocomotionConfig(proprio_dim=proprio_dim, num_actions=num_actions,
                                                       init_std=init_std, network=network))
        return perc, actor, pcfg
    missing = [k for k in ORACLE_LOCOMOTION_INPUTS if k not in perc.out_keys]
    if missing:
        raise ValueError(f"student.locomotion=oracle (the teacher's actor, frozen) reads {missing}, which "
                         f"perception {perception!r} does not estimate: use rmah or rmab")
    ocfg = OracleConfig(**oracle_config)
    want = {"proprio_dim": proprio_dim, "num_actions": num_actions, "num_goals": num_goals,
            "latent_dim": pcfg.io.latent_dim, "priv_latent_dim": pcfg.io.priv_latent_dim}
    have = {"proprio_dim": ocfg.proprio_dim, "num_actions": ocfg.num_actions, "num_goals": ocfg.num_goals,
            "latent_dim": ocfg.latent_dim, "priv_latent_dim": ocfg.priv_latent_dim}
    bad = {k: (have[k], want[k]) for k in want if have[k] != want[k]}
    if bad:
        raise ValueError(f"the oracle's actor cannot be the student's locomotion: sizes (oracle, student) {bad}")
    return perc, make_oracle_locomotion_actor(oracle_network_class(ocfg.network).actor_class(ocfg)), pcfg


def hold_keys(perception) -> tuple[str, ...]:
    """The outputs :class:`PerceptionHold` keeps between perception ticks for a perception module
    (torch or exported): ``z_uni``, ``delta_g0``, ``goals_uni``, and ``priv_latent_uni`` when the
    module writes it (the RMA adapters)."""
    return ("z_uni", "delta_g0", "goals_uni") + (("priv_latent_uni",) if "priv_latent_uni" in perception.out_keys else ())


def make_student(env: HikingEnv, perception: str = "tcvit", preset: str = "cpu",
                 init_std: float = 1.0, oracle_config: Mapping | None = None,
                 record_features: bool = False, network: str = LocomotionConfig.network) -> StudentPolicy:
    """Build the student sized for ``env`` (student or eval mode; depth on, or off for a
    perception that reads none: RMA-B).

    Args:
        env: the (untransformed) hiking env.
        perception: a name of :func:`legoh_rl.modules.perception.make_perception`
            (``tcvit``, ``tcvit_ct``, ``vanilla``, ``eph``, ``rmah``, ``rmab``).
        preset: ``"cpu"`` (64x64) or ``"paper"`` (128x128); must match the env's depth size.
        init_std: initial action std of the locomotion actor (the unified recipe passes its
            teacher's).
        oracle_config: the teacher's ``OracleConfig`` fields for a frozen-oracle locomotion
            (RMA, see :func:`student_networks`); ``None``: the student's own MLP.
        record_features: acting also records the perception encoder's output
            (``perception_features``) so that training passes can run the encoder on a fraction
            of the ticks (:class:`PerceptionHold`'s ``feature_key``); only for perceptions built
            as encoder then memory (``tcvit``, ``tcvit_ct``, ``vanilla``, ``eph``).
        network: the learned locomotion network's name (:func:`student_networks`).
    """
    spec = env.observation_spec
    size = spec["depth"].shape[-1] if env.cfg.depth_enabled else env.cfg.depth_camera.width
    perc, actor, pcfg = student_networks(perception, preset, spec["proprio"].shape[-1], size,
                                         spec["expert_goals"].shape[-2], env.A, init_std, oracle_config,
                                         network)
    if not env.cfg.depth_enabled and {"depth", "depth_goal_stack"} & set(perc.in_keys):
        raise ValueError(f"perception {perception!r} reads depth: build the env with the depth camera "
                         "(mode 'student' or 'eval', depth not false)")
    feature_key = PerceptionKeys().features if record_features else None
    hold = PerceptionHold(perc, hold_keys=hold_keys(perc), feature_key=feature_key)
    return StudentPolicy(perc, hold, actor, pcfg.io.history_len)


def student_env(env: HikingEnv, student: StudentPolicy) -> TransformedEnv:
    """Wrap ``env`` with the student's transforms and state primers."""
    transforms = [InitTracker()]
    if "depth" in env.observation_spec.keys():  # a blind student's env has no camera
        transforms += [DepthHistory(), GoalTiling()]
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
