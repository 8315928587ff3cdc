"""TensorDictModules of LEGO-H: TC-ViT and baselines, locomotion policy, oracle, adaptation, VAE.

Each network is a plain ``nn.Module`` with a dataclass config (:mod:`.configs`); builders
wrap them with the TensorDict keys of ``docs/keys.md`` (renamable through :mod:`.keys`).
See ``docs/modules.md``.
"""

from legoh_rl.modules.adaptation import ProprioHistoryEncoder, make_adaptation_module
from legoh_rl.modules.baselines import make_eph, make_rmab, make_rmah, make_vanilla
from legoh_rl.modules.causal_transformer import CausalTransformerMemory
from legoh_rl.modules.configs import (
    AdaptationConfig,
    CausalTransformerConfig,
    DepthCNNConfig,
    HistoryEncoderConfig,
    LocomotionConfig,
    OracleConfig,
    PerceptionConfig,
    PerceptionIO,
    ViViTConfig,
    perception_config,
)
from legoh_rl.modules.distributions import GaussianHead, make_gaussian_actor
from legoh_rl.modules.goal_adaptation import (
    PerceptionHeads,
    make_memory_perception,
    perception_output_spec,
)
from legoh_rl.modules.keys import AdaptationKeys, LocomotionKeys, OracleKeys, PerceptionKeys
from legoh_rl.modules.locomotion import (
    LOCOMOTION_NETWORKS,
    LocomotionNet,
    make_locomotion_actor,
    make_locomotion_network,
    make_oracle_locomotion_actor,
    register_locomotion_network,
)
from legoh_rl.modules.masked_vae import MaskedVAE, MaskedVAEConfig, make_masked_vae_module
from legoh_rl.modules.mlp import build_mlp, unit_normalize
from legoh_rl.modules.oracle import (
    ORACLE_NETWORKS,
    OracleNetworks,
    make_oracle_actor,
    make_oracle_actor_critic,
    make_oracle_critic,
    make_oracle_networks,
    register_oracle_network,
)
from legoh_rl.modules.perception import (
    PERCEPTION_BUILDERS,
    make_perception,
    make_tcvit,
    make_tcvit_ct,
    make_tcvit_encoder,
)
from legoh_rl.modules.tcvit import GoalConditionedViViT, TCViTEncoder

__all__ = [
    "AdaptationConfig",
    "AdaptationKeys",
    "CausalTransformerConfig",
    "CausalTransformerMemory",
    "DepthCNNConfig",
    "GaussianHead",
    "GoalConditionedViViT",
    "HistoryEncoderConfig",
    "LocomotionConfig",
    "LocomotionKeys",
    "LocomotionNet",
    "LOCOMOTION_NETWORKS",
    "make_locomotion_network",
    "register_locomotion_network",
    "MaskedVAE",
    "MaskedVAEConfig",
    "OracleConfig",
    "OracleKeys",
    "OracleNetworks",
    "ORACLE_NETWORKS",
    "make_oracle_networks",
    "register_oracle_network",
    "PERCEPTION_BUILDERS",
    "PerceptionConfig",
    "PerceptionHeads",
    "PerceptionIO",
    "PerceptionKeys",
    "ProprioHistoryEncoder",
    "TCViTEncoder",
    "ViViTConfig",
    "build_mlp",
    "make_adaptation_module",
    "make_eph",
    "make_gaussian_actor",
    "make_locomotion_actor",
    "make_oracle_locomotion_actor",
    "make_masked_vae_module",
    "make_memory_perception",
    "make_oracle_actor",
    "make_oracle_actor_critic",
    "make_oracle_critic",
    "make_perception",
    "perception_output_spec",
    "make_rmab",
    "make_rmah",
    "make_tcvit",
    "make_tcvit_ct",
    "make_tcvit_encoder",
    "make_vanilla",
    "perception_config",
    "unit_normalize",
]
