"""Dataclass configs of every network in :mod:`legoh_rl.modules`, and the named presets.

Sizes that depend on the robot or the env (``proprio_dim``, ``num_actions``,
``privileged_dim``) have no default: they come from the env specs (``docs/keys.md``:
``proprio`` is ``3 + 2 + 3A + 2``, ``privileged`` is ``8 + A``). Everything else defaults to
the paper's appendix where it states a value, and to the CPU-sized choice otherwise.

Perception presets (:func:`perception_config`):

* ``"cpu"``: 64x64 depth, 16x16 patches (16 spatial tokens per frame), dim 64, 4 heads,
  6 factorised space-time layers. Fast enough for batch-1 control on 2 CPU cores.
* ``"paper"``: 128x128 depth, 16x16 patches (64 tokens per frame), dim 152, 4 heads,
  6 layers, sized to land on the paper's 31.25M parameters / 0.686 G multiply-accumulates
  (see ``docs/modules.md``); meant for GPUs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

__all__ = [
    "AdaptationConfig",
    "CausalTransformerConfig",
    "DepthCNNConfig",
    "HistoryEncoderConfig",
    "LocomotionConfig",
    "OracleConfig",
    "PERCEPTION_PRESETS",
    "PerceptionConfig",
    "PerceptionIO",
    "ViViTConfig",
    "perception_config",
]


def _positive(name: str, value: float) -> None:
    if value <= 0:
        raise ValueError(f"{name} must be positive, got {value!r}")


def _positive_seq(name: str, values) -> None:
    if len(values) == 0 or any(int(v) <= 0 for v in values):
        raise ValueError(f"{name} must be a non-empty sequence of positive ints, got {values!r}")


@dataclass
class PerceptionIO:
    """Input/output sizes shared by every perception network.

    Attributes:
        proprio_dim: D, size of ``proprio`` (and of each row of ``proprio_history``).
        image_size: H = W of ``depth`` and ``depth_goal_stack``.
        num_frames: T of ``depth_goal_stack`` (4: 16 frames downsampled to 4).
        goal_channels: G tiled goal planes per frame; the stack has ``1 + G`` channels.
        num_goals: N anticipated goals in ``goals_uni`` (N, 2).
        latent_dim: size of ``z_uni``; must equal the oracle's scandot latent (32).
        gps_dim: size of ``goal_gps`` and ``waypoint_gps`` (2).
        history_len: T_h rows of ``proprio_history`` (RMA baselines).
        priv_latent_dim: size of ``priv_latent_uni``, the RMA adapters' estimate of the
            oracle's privileged latent; must equal the oracle's (20).
        num_waypoints: M, intermediate waypoints given to the network (the paper's D_rm):
            1 (default, LEGO-H) reads ``waypoint_gps`` (2,); 0 for a task without a
            waypoint: no ``waypoint_gps`` input, the key is never read, and the memory-input
            MLP (or the RMA trunk) is ``gps_dim`` narrower. Every committed checkpoint has
            M = 1.
    """

    proprio_dim: int
    image_size: int = 64
    num_frames: int = 4
    goal_channels: int = 1
    num_goals: int = 3
    latent_dim: int = 32
    gps_dim: int = 2
    history_len: int = 10
    priv_latent_dim: int = 20
    num_waypoints: int = 1

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        for name in ("proprio_dim", "image_size", "num_frames", "num_goals", "latent_dim",
                     "gps_dim", "history_len", "priv_latent_dim"):
            _positive(f"PerceptionIO.{name}", getattr(self, name))
        if self.goal_channels < 0:
            raise ValueError(f"PerceptionIO.goal_channels must be >= 0, got {self.goal_channels}")
        if isinstance(self.num_waypoints, bool) or self.num_waypoints not in (0, 1):
            raise ValueError(f"PerceptionIO.num_waypoints must be 0 or 1, got {self.num_waypoints!r}")

    @property
    def gps_inputs(self) -> int:
        """Number of GPS vectors the networks read: ``goal_gps`` plus M ``waypoint_gps``."""
        return 1 + int(self.num_waypoints)

    @property
    def stack_channels(self) -> int:
        """Channels per frame of ``depth_goal_stack``: ``1 + goal_channels``."""
        return 1 + self.goal_channels


@dataclass
class ViViTConfig:
    """Goal-conditioned factorised space-time transformer (TC-ViT part a).

    Attributes:
        patch_size: square patch side P; ``image_size`` must be divisible by it.
        dim: token width. heads: attention heads (must divide ``dim``).
        layers: factorised blocks, each = spatial attention + temporal attention + MLP.
        mlp_ratio: hidden width of the block MLP relative to ``dim``.
        dropout: dropout in attention and MLP.
        alpha_pooling: ``"flatten"`` (alpha = all T*S tokens flattened, as in the paper's
            "flattened feature vector") or ``"mean"`` (alpha = mean token, small).
    """

    patch_size: int = 16
    dim: int = 64
    heads: int = 4
    layers: int = 6
    mlp_ratio: float = 2.0
    dropout: float = 0.0
    alpha_pooling: str = "flatten"

    def validate(self, image_size: int) -> None:
        """Raise ``ValueError`` naming the first bad field (needs the image size)."""
        for name in ("patch_size", "dim", "heads", "layers", "mlp_ratio"):
            _positive(f"ViViTConfig.{name}", getattr(self, name))
        if image_size % self.patch_size:
            raise ValueError(
                f"image size {image_size} is not divisible by ViViTConfig.patch_size "
                f"{self.patch_size}"
            )
        if self.dim % self.heads:
            raise ValueError(
                f"ViViTConfig.dim {self.dim} is not divisible by ViViTConfig.heads {self.heads}"
            )
        if self.alpha_pooling not in ("flatten", "mean"):
            raise ValueError(
                f"ViViTConfig.alpha_pooling must be 'flatten' or 'mean', got {self.alpha_pooling!r}"
            )


@dataclass
class DepthCNNConfig:
    """Shallow CNN on depth images: conv (ELU) layers, flatten, linear (ELU) to ``out_dim``.

    ``channels``, ``kernel_sizes`` and ``strides`` list one entry per conv layer; padding
    is ``kernel // 2``.
    """

    channels: tuple[int, ...] = (16, 32, 32)
    kernel_sizes: tuple[int, ...] = (5, 3, 3)
    strides: tuple[int, ...] = (2, 2, 2)
    out_dim: int = 64

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        _positive_seq("DepthCNNConfig.channels", self.channels)
        _positive_seq("DepthCNNConfig.kernel_sizes", self.kernel_sizes)
        _positive_seq("DepthCNNConfig.strides", self.strides)
        if not (len(self.channels) == len(self.kernel_sizes) == len(self.strides)):
            raise ValueError(
                "DepthCNNConfig.channels, kernel_sizes and strides must have the same length, "
                f"got {len(self.channels)}, {len(self.kernel_sizes)}, {len(self.strides)}"
            )
        _positive("DepthCNNConfig.out_dim", self.out_dim)


@dataclass
class HistoryEncoderConfig:
    """Encoder of ``proprio_history`` (T_h, D) (adaptation module, RMA baselines).

    ``kind="conv"``: per-step linear embedding to ``embed_dim`` then 1D convolutions over
    time (RMA / Extreme Parkour's history encoder), flatten, linear. ``kind="mlp"``: the
    flattened history through an MLP of widths ``mlp_layers``.
    """

    kind: str = "conv"
    embed_dim: int = 32
    channels: tuple[int, ...] = (32, 32)
    kernel_sizes: tuple[int, ...] = (4, 2)
    strides: tuple[int, ...] = (2, 1)
    mlp_layers: tuple[int, ...] = (256, 128)

    def validate(self, history_len: int) -> None:
        """Raise ``ValueError`` naming the first bad field (needs T_h)."""
        if self.kind not in ("conv", "mlp"):
            raise ValueError(f"HistoryEncoderConfig.kind must be 'conv' or 'mlp', got {self.kind!r}")
        if self.kind == "mlp":
            _positive_seq("HistoryEncoderConfig.mlp_layers", self.mlp_layers)
            return
        _positive("HistoryEncoderConfig.embed_dim", self.embed_dim)
        _positive_seq("HistoryEncoderConfig.channels", self.channels)
        if not (len(self.channels) == len(self.kernel_sizes) == len(self.strides)):
            raise ValueError(
                "HistoryEncoderConfig.channels, kernel_sizes and strides must have the same "
                f"length, got {len(self.channels)}, {len(self.kernel_sizes)}, {len(self.strides)}"
            )
        length = history_len
        for k, s in zip(self.kernel_sizes, self.strides, strict=True):
            length = (length - k) // s + 1
            if length < 1:
                raise ValueError(
                    f"history length {history_len} is too short for the conv history encoder "
                    f"(kernel_sizes={self.kernel_sizes}, strides={self.strides})"
                )


@dataclass
class CausalTransformerConfig:
    """Causal transformer replacing the GRU in the ``tcvit_ct`` ablation.

    Attributes:
        window: W, steps attended (current step + W-1 kept in a rolling buffer).
        dim, heads, layers, mlp_ratio, dropout: transformer size.
    """

    window: int = 8
    dim: int = 64
    heads: int = 4
    layers: int = 2
    mlp_ratio: float = 2.0
    dropout: float = 0.0

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        for name in ("window", "dim", "heads", "layers", "mlp_ratio"):
            _positive(f"CausalTransformerConfig.{name}", getattr(self, name))
        if self.window < 2:
            raise ValueError(f"CausalTransformerConfig.window must be >= 2, got {self.window}")
        if self.dim % self.heads:
            raise ValueError(
                f"CausalTransformerConfig.dim {self.dim} is not divisible by heads {self.heads}"
            )


@dataclass
class PerceptionConfig:
    """Everything the perception registry (:func:`make_perception`) needs.

    Attributes:
        io: shared input/output sizes.
        vit: TC-ViT spatio-temporal encoder (part a, alpha).
        cnn: shallow CNN on the current depth frame (TC-ViT part b, beta); also the depth
            CNN of the EP-H and RMA-H baselines.
        fusion_layers: widths of the fusion MLP concat(alpha, beta) -> gamma; the last
            entry is ``gamma`` 's size.
        memory_in_layers: the 2-layer MLP over (gamma, goal_gps, waypoint_gps, proprio)
            before the GRU (or causal transformer); without ``waypoint_gps`` when
            ``io.num_waypoints`` is 0.
        gru_hidden, gru_layers: GRU size.
        latent_tanh: squash ``z_uni`` with Tanh, like the oracle's scandot latent it imitates.
        ct: causal transformer of the ``tcvit_ct`` ablation.
        vanilla_cnn: conv encoder over the whole depth-goal stack (``vanilla`` ConvGRU).
        eph_depth_cutoff: EP-H's near-range cut-off on normalised depth, in (0, 1].
        history: proprio-history encoder (RMA-H / RMA-B).
        rma_layers: MLP of the RMA adapters before the output heads.
    """

    io: PerceptionIO
    vit: ViViTConfig = field(default_factory=ViViTConfig)
    cnn: DepthCNNConfig = field(default_factory=DepthCNNConfig)
    fusion_layers: tuple[int, ...] = (128, 64)
    memory_in_layers: tuple[int, ...] = (128, 128)
    gru_hidden: int = 128
    gru_layers: int = 1
    latent_tanh: bool = True
    ct: CausalTransformerConfig = field(default_factory=CausalTransformerConfig)
    vanilla_cnn: DepthCNNConfig = field(
        default_factory=lambda: DepthCNNConfig(channels=(32, 64, 64), out_dim=128)
    )
    eph_depth_cutoff: float = 0.4
    history: HistoryEncoderConfig = field(default_factory=HistoryEncoderConfig)
    rma_layers: tuple[int, ...] = (128, 128)

    def validate(self) -> None:
        """Validate every sub-config; raise ``ValueError`` naming the first bad value."""
        self.io.validate()
        self.vit.validate(self.io.image_size)
        self.cnn.validate()
        self.vanilla_cnn.validate()
        self.ct.validate()
        self.history.validate(self.io.history_len)
        _positive_seq("PerceptionConfig.fusion_layers", self.fusion_layers)
        _positive_seq("PerceptionConfig.memory_in_layers", self.memory_in_layers)
        _positive_seq("PerceptionConfig.rma_layers", self.rma_layers)
        _positive("PerceptionConfig.gru_hidden", self.gru_hidden)
        _positive("PerceptionConfig.gru_layers", self.gru_layers)
        if not 0.0 < self.eph_depth_cutoff <= 1.0:
            raise ValueError(
                f"PerceptionConfig.eph_depth_cutoff must be in (0, 1], got {self.eph_depth_cutoff}"
            )

    @property
    def gamma_dim(self) -> int:
        """Size of gamma, the fused TC-ViT feature."""
        return int(self.fusion_layers[-1])


def _cpu_preset(io: PerceptionIO) -> PerceptionConfig:
    return PerceptionConfig(io=io)


def _paper_preset(io: PerceptionIO) -> PerceptionConfig:
    # 128x128, 16x16 patches -> 64 tokens/frame, 256 space-time tokens of width 152.
    # Sized so the full TC-ViT has ~31.3M parameters and ~0.68 G multiply-accumulates per
    # sample (the paper: 31.25M / 0.686 G), and tcvit_ct ~55M / ~0.78 G (paper: 55.92M /
    # 0.785 G); see benchmarks/module_cost.py.
    return PerceptionConfig(
        io=io,
        vit=ViViTConfig(patch_size=16, dim=152, heads=4, layers=6, mlp_ratio=4.0),
        cnn=DepthCNNConfig(channels=(32, 64, 64), kernel_sizes=(5, 3, 3), strides=(2, 2, 2),
                           out_dim=512),
        fusion_layers=(466, 256),
        memory_in_layers=(512, 512),
        gru_hidden=512,
        ct=CausalTransformerConfig(window=4, dim=512, heads=8, layers=8, mlp_ratio=4.0),
        vanilla_cnn=DepthCNNConfig(channels=(32, 64, 128, 128), kernel_sizes=(5, 3, 3, 3),
                                   strides=(2, 2, 2, 2), out_dim=512),
        history=HistoryEncoderConfig(embed_dim=64, channels=(64, 64)),
        rma_layers=(512, 256),
    )


PERCEPTION_PRESETS = {"cpu": _cpu_preset, "paper": _paper_preset}


def perception_config(preset: str, proprio_dim: int, **io_overrides) -> PerceptionConfig:
    """Named perception preset: ``"cpu"`` (64x64) or ``"paper"`` (128x128).

    Args:
        preset: one of :data:`PERCEPTION_PRESETS`.
        proprio_dim: D of ``proprio`` (``3 + 2 + 3A + 2``).
        **io_overrides: any other :class:`PerceptionIO` field (``num_goals``, ...).
            ``image_size`` defaults to 64 (cpu) / 128 (paper).

    Raises:
        ValueError: on an unknown preset or a bad field.
    """
    if preset not in PERCEPTION_PRESETS:
        raise ValueError(
            f"unknown perception preset {preset!r}; valid presets: {sorted(PERCEPTION_PRESETS)}"
        )
    io_fields = {f.name for f in dataclasses.fields(PerceptionIO)}
    bad = sorted(set(io_overrides) - io_fields)
    if bad:
        raise ValueError(f"unknown PerceptionIO fields {bad}; valid fields: {sorted(io_fields)}")
    io_overrides.setdefault("image_size", 128 if preset == "paper" else 64)
    cfg = PERCEPTION_PRESETS[preset](PerceptionIO(proprio_dim=proprio_dim, **io_overrides))
    cfg.validate()
    return cfg


@dataclass
class OracleConfig:
    """Oracle actor-critic (paper appendix "Network Architectures").

    Attributes:
        proprio_dim: D of ``proprio``. num_actions: A. privileged_dim: P of ``privileged``.
        scandots_dim: size of ``scandots`` (132 = 12 x 11; 222 with the env's ``foot_scan``).
        num_goals: N rows of ``expert_goals`` (N, 2), flattened into the actor input.
        scandot_layers: scandot encoder widths; the last is ``z_tea`` 's size (32).
        priv_layers: privileged encoder widths; the last is ``priv_latent`` 's size (20).
        actor_layers, critic_layers: MLP widths [512, 256, 128]; a final linear maps the
            last width to A action means (actor) or 1 value (critic).
        activation: hidden non-linearity (ELU).
        encoder_out_activation: after the scandot encoder's last layer (Tanh, paper).
        priv_out_activation: after the privileged encoder's last layer (ELU, as in
            Extreme Parkour's encoder, which the paper builds on).
        body_out_activation: after the last actor/critic MLP layer (Tanh, paper: "Tanh for
            the output layer"; the linear mean/value head follows it).
        init_std: initial state-independent action std.
        max_std: if set, a ceiling on the action std (``None``: no ceiling).
        loc_bound: if set, ``loc = loc_bound * tanh(head)`` bounds the action means; ``None``
            (default) keeps the linear head unbounded like rsl_rl.
        share_encoders: the critic reuses the actor's scandot/privileged encoders (``True``)
            or has its own copies (``False``, default; like rsl_rl's separate networks).
        network: the name of the network class in
            :data:`legoh_rl.modules.oracle.ORACLE_NETWORKS` (``"mlp"``: the paper's
            :class:`~legoh_rl.modules.oracle.OracleNetworks`); a checkpoint that records none
            was made with ``"mlp"``.
    """

    proprio_dim: int
    num_actions: int
    privileged_dim: int
    scandots_dim: int = 132
    num_goals: int = 3
    scandot_layers: tuple[int, ...] = (128, 64, 32)
    priv_layers: tuple[int, ...] = (64, 20)
    actor_layers: tuple[int, ...] = (512, 256, 128)
    critic_layers: tuple[int, ...] = (512, 256, 128)
    activation: str = "elu"
    encoder_out_activation: str = "tanh"
    priv_out_activation: str = "elu"
    body_out_activation: str = "tanh"
    init_std: float = 1.0
    max_std: float | None = None
    loc_bound: float | None = None
    share_encoders: bool = False
    network: str = "mlp"

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        if not isinstance(self.network, str) or not self.network:
            raise ValueError(f"OracleConfig.network must be a registered network's name, got {self.network!r}")
        for name in ("proprio_dim", "num_actions", "privileged_dim", "scandots_dim",
                     "num_goals", "init_std"):
            _positive(f"OracleConfig.{name}", getattr(self, name))
        for name in ("scandot_layers", "priv_layers", "actor_layers", "critic_layers"):
            _positive_seq(f"OracleConfig.{name}", getattr(self, name))
        if self.loc_bound is not None:
            _positive("OracleConfig.loc_bound", self.loc_bound)
        if self.max_std is not None:
            _positive("OracleConfig.max_std", self.max_std)

    @property
    def latent_dim(self) -> int:
        """Size of ``z_tea``."""
        return int(self.scandot_layers[-1])

    @property
    def priv_latent_dim(self) -> int:
        """Size of ``priv_latent``."""
        return int(self.priv_layers[-1])


@dataclass
class LocomotionConfig:
    """Student locomotion module: a network over (z_uni, proprio, delta_g0, goal_next).

    Attributes:
        proprio_dim: D. num_actions: A. latent_dim: size of ``z_uni`` (32).
        goal_dim: size of ``delta_g0`` and ``goal_next`` ((cos, sin): 2).
        layers, activation, body_out_activation, init_std, loc_bound: as in
            :class:`OracleConfig` (same distribution and head as the oracle actor).
        network: the class's name in
            :data:`~legoh_rl.modules.locomotion.LOCOMOTION_NETWORKS` (``"mlp"``: the paper's MLP,
            :class:`~legoh_rl.modules.locomotion.LocomotionNet`).
    """

    proprio_dim: int
    num_actions: int
    latent_dim: int = 32
    goal_dim: int = 2
    layers: tuple[int, ...] = (512, 256, 128)
    activation: str = "elu"
    body_out_activation: str = "tanh"
    init_std: float = 1.0
    loc_bound: float | None = None
    network: str = "mlp"

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        if not isinstance(self.network, str) or not self.network:
            raise ValueError(f"LocomotionConfig.network must be a registered network's name, got {self.network!r}")
        for name in ("proprio_dim", "num_actions", "latent_dim", "goal_dim", "init_std"):
            _positive(f"LocomotionConfig.{name}", getattr(self, name))
        _positive_seq("LocomotionConfig.layers", self.layers)
        if self.loc_bound is not None:
            _positive("LocomotionConfig.loc_bound", self.loc_bound)


@dataclass
class AdaptationConfig:
    """Adaptation module: ``proprio_history`` (T_h, D) -> privileged-latent estimate.

    Attributes:
        proprio_dim: D. history_len: T_h (10). latent_dim: the oracle's ``priv_latent``
            size (20). encoder: history encoder (1D conv by default).
        out_activation: after the output linear (``None``: linear regression output).
    """

    proprio_dim: int
    history_len: int = 10
    latent_dim: int = 20
    encoder: HistoryEncoderConfig = field(default_factory=HistoryEncoderConfig)
    out_activation: str | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        for name in ("proprio_dim", "history_len", "latent_dim"):
            _positive(f"AdaptationConfig.{name}", getattr(self, name))
        self.encoder.validate(self.history_len)
