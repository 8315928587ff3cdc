"""TC-ViT builders and the perception registry (``make_perception(name, cfg)``).

Every registered network reads some of ``depth_goal_stack``, ``depth``, ``goal_gps``,
``waypoint_gps`` (not with ``PerceptionIO(num_waypoints=0)``), ``proprio``,
``proprio_history`` (and ``is_init``) and writes ``z_uni`` (latent,), ``delta_g0`` (2,) and
``goals_uni`` (N, 2); its ``spec`` attribute gives those shapes (from the config).

======== ================================================================ ===========
name     network                                                          memory
======== ================================================================ ===========
tcvit    TC-ViT: goal-conditioned ViViT + current-frame CNN + MLP + GRU   GRU
tcvit_ct TC-ViT with a causal transformer over the last W steps            rolling buf
vanilla  ConvGRU: conv encoder over the depth-goal stack + GRU             GRU
eph      EP-H: CNN on the cut-off current depth frame + GRU                GRU
rmah     RMA-H: proprio-history + depth adapter (feed-forward)             none
rmab     RMA-B: blind proprio-history adapter (feed-forward)               none
======== ================================================================ ===========
"""

from __future__ import annotations

from collections.abc import Callable

from tensordict.nn import TensorDictModule, TensorDictSequential

from legoh_rl.modules.baselines import make_eph, make_rmab, make_rmah, make_vanilla
from legoh_rl.modules.configs import PerceptionConfig
from legoh_rl.modules.goal_adaptation import make_memory_perception
from legoh_rl.modules.keys import PerceptionKeys
from legoh_rl.modules.tcvit import TCViTEncoder
from legoh_rl.registry import Registry

__all__ = [
    "PERCEPTION_BUILDERS",
    "make_perception",
    "make_tcvit",
    "make_tcvit_ct",
    "make_tcvit_encoder",
]


def make_tcvit_encoder(
    cfg: PerceptionConfig, keys: PerceptionKeys | None = None
) -> TensorDictModule:
    """TensorDictModule ``(depth_goal_stack, depth) -> features`` (gamma, ``cfg.gamma_dim``)."""
    cfg.validate()
    keys = keys or PerceptionKeys()
    return TensorDictModule(
        TCViTEncoder(cfg), in_keys=[keys.depth_goal_stack, keys.depth], out_keys=[keys.features]
    )


def make_tcvit(cfg: PerceptionConfig, keys: PerceptionKeys | None = None) -> TensorDictSequential:
    """TC-ViT with its recurrent goal adaptation (GRU).

    Inputs: ``depth_goal_stack`` (T, 1+G, H, W), ``depth`` (1, H, W), ``goal_gps`` (2,),
    ``waypoint_gps`` (2,) (only when ``cfg.io.num_waypoints`` is 1, the default),
    ``proprio`` (D,), ``is_init`` (1,), ``perception_hidden`` (gru_layers, gru_hidden; zeros
    if absent). Outputs: ``z_uni`` (latent_dim,), ``delta_g0`` (2,), ``goals_uni``
    (num_goals, 2) and ``("next", "perception_hidden")``; ``spec`` holds the outputs'
    feature shapes (:func:`~legoh_rl.modules.goal_adaptation.perception_output_spec`).
    """
    encoder = make_tcvit_encoder(cfg, keys)
    return make_memory_perception(encoder, cfg.gamma_dim, cfg, keys, memory="gru")


def make_tcvit_ct(
    cfg: PerceptionConfig, keys: PerceptionKeys | None = None
) -> TensorDictSequential:
    """TC-ViT with a causal transformer over the last ``cfg.ct.window`` steps instead of a GRU.

    The window is kept in the TensorDict as ``perception_context`` (W-1, dim) and
    ``perception_context_valid`` (W-1,) (see
    :class:`~legoh_rl.modules.causal_transformer.CausalTransformerMemory`).
    """
    encoder = make_tcvit_encoder(cfg, keys)
    return make_memory_perception(encoder, cfg.gamma_dim, cfg, keys, memory="ct")


#: perception builders by name (the unified recipe's ``student.perception``), each
#: ``builder(cfg: PerceptionConfig, keys: PerceptionKeys | None) -> TensorDictSequential``
PERCEPTION_BUILDERS: Registry[Callable[..., TensorDictSequential]] = Registry(
    "perception network", hint="PERCEPTION_BUILDERS.register(name, builder) in legoh_rl.modules.perception adds one",
    entries={"tcvit": make_tcvit, "tcvit_ct": make_tcvit_ct, "vanilla": make_vanilla, "eph": make_eph,
             "rmah": make_rmah, "rmab": make_rmab})


def make_perception(
    name: str, cfg: PerceptionConfig, keys: PerceptionKeys | None = None
) -> TensorDictSequential:
    """Build the perception network registered as ``name`` (see the module table).

    Raises:
        ValueError: for an unknown ``name`` (the message lists the registered names).
    """
    return PERCEPTION_BUILDERS.lookup(name)(cfg, keys)
