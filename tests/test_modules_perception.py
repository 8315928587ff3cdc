"""Perception networks: TC-ViT and the baseline registry (shapes, gradients, errors, sizes)."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict

from legoh_rl.modules import (
    PERCEPTION_BUILDERS,
    PerceptionKeys,
    make_perception,
    make_tcvit_encoder,
    perception_config,
)
from legoh_rl.modules.configs import ViViTConfig
from legoh_rl.modules.tcvit import GoalConditionedViViT

PROPRIO = 37  # 3 + 2 + 3 * 10 + 2 for A = 10; any value works


def make_inputs(cfg, batch=(2,), seed=0, recurrent_state=False):
    g = torch.Generator().manual_seed(seed)
    io = cfg.io
    h = io.image_size
    td = TensorDict(
        {
            "depth_goal_stack": torch.rand(*batch, io.num_frames, io.stack_channels, h, h, generator=g),
            "depth": torch.rand(*batch, 1, h, h, generator=g),
            "goal_gps": torch.randn(*batch, 2, generator=g),
            "waypoint_gps": torch.randn(*batch, 2, generator=g),
            "proprio": torch.randn(*batch, io.proprio_dim, generator=g),
            "proprio_history": torch.randn(*batch, io.history_len, io.proprio_dim, generator=g),
            "is_init": torch.zeros(*batch, 1, dtype=torch.bool),
        },
        batch_size=batch,
    )
    if recurrent_state:  # non-zero memory so the recurrent weights get gradients too
        td["perception_hidden"] = torch.randn(*batch, cfg.gru_layers, cfg.gru_hidden, generator=g)
        td["perception_context"] = torch.randn(*batch, cfg.ct.window - 1, cfg.ct.dim, generator=g)
        td["perception_context_valid"] = torch.ones(*batch, cfg.ct.window - 1, dtype=torch.bool)
    return td


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """Tiny batches: one intra-op thread avoids OpenMP stalls on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def cpu_cfg():
    return perception_config("cpu", proprio_dim=PROPRIO)


@pytest.mark.parametrize("name", sorted(PERCEPTION_BUILDERS))
def test_registry_same_keys_and_shapes(cpu_cfg, name):
    net = make_perception(name, cpu_cfg)
    out = net(make_inputs(cpu_cfg, batch=(3,)))
    assert out["z_uni"].shape == (3, 32)
    assert out["delta_g0"].shape == (3, 2)
    assert out["goals_uni"].shape == (3, 3, 2)
    for key in ("z_uni", "delta_g0", "goals_uni"):
        assert key in net.out_keys
        assert torch.isfinite(out[key]).all()
    # angles are unit (cos, sin) vectors, the latent is Tanh-bounded like z_tea
    torch.testing.assert_close(out["delta_g0"].norm(dim=-1), torch.ones(3))
    torch.testing.assert_close(out["goals_uni"].norm(dim=-1), torch.ones(3, 3))
    assert out["z_uni"].abs().max() <= 1.0


@pytest.mark.parametrize("name", sorted(PERCEPTION_BUILDERS))
def test_gradients_reach_every_parameter(cpu_cfg, name):
    torch.manual_seed(0)
    net = make_perception(name, cpu_cfg)
    out = net(make_inputs(cpu_cfg, recurrent_state=True))
    g = torch.Generator().manual_seed(1)
    outputs = ("z_uni", "delta_g0", "goals_uni") + (("priv_latent_uni",) if "priv_latent_uni" in net.out_keys else ())
    loss = sum((out[k] * torch.randn(out[k].shape, generator=g)).sum() for k in outputs)
    loss.backward()
    for pname, p in net.named_parameters():
        assert p.grad is not None, f"{name}: no gradient for {pname}"
        assert p.grad.abs().sum() > 0, f"{name}: zero gradient for {pname}"


@pytest.mark.parametrize("name", sorted(PERCEPTION_BUILDERS))
def test_only_the_rma_adapters_estimate_the_privileged_latent(cpu_cfg, name):
    net = make_perception(name, cpu_cfg)
    rma = name in ("rmah", "rmab")
    assert ("priv_latent_uni" in net.out_keys) == rma and ("priv_latent_uni" in net.spec.keys()) == rma
    if rma:
        out = net(make_inputs(cpu_cfg, recurrent_state=True))
        assert out["priv_latent_uni"].shape[-1] == cpu_cfg.io.priv_latent_dim == 20
        assert net.spec["priv_latent_uni"].shape == (20,)


def test_num_goals_and_goal_channels_come_from_config():
    cfg = perception_config("cpu", proprio_dim=43, num_goals=5, goal_channels=2)
    out = make_perception("tcvit", cfg)(make_inputs(cfg))
    assert out["goals_uni"].shape == (2, 5, 2)


def test_recurrent_batch_shapes(cpu_cfg):
    """Encoders accept any leading batch dims ([N, T] training batches)."""
    enc = make_tcvit_encoder(cpu_cfg)
    out = enc(make_inputs(cpu_cfg, batch=(2, 3)))
    assert out["perception_features"].shape == (2, 3, cpu_cfg.gamma_dim)


def test_unknown_name_lists_valid_names(cpu_cfg):
    with pytest.raises(ValueError) as err:
        make_perception("resnet", cpu_cfg)
    for name in PERCEPTION_BUILDERS:
        assert name in str(err.value)


def test_unknown_preset_errors():
    with pytest.raises(ValueError, match="cpu"):
        perception_config("huge", proprio_dim=PROPRIO)


def test_patch_size_must_divide_image():
    with pytest.raises(ValueError, match="not divisible by ViViTConfig.patch_size 16"):
        GoalConditionedViViT(2, 4, 72, ViViTConfig(patch_size=16))
    with pytest.raises(ValueError, match="image size 72"):
        perception_config("cpu", proprio_dim=PROPRIO, image_size=72)


def test_wrong_input_shape_names_the_input(cpu_cfg):
    net = make_perception("tcvit", cpu_cfg)
    td = make_inputs(cpu_cfg)
    td["depth_goal_stack"] = torch.rand(2, 4, 2, 32, 32)
    with pytest.raises(ValueError, match="depth_goal_stack"):
        net(td)


def test_custom_keys(cpu_cfg):
    keys = PerceptionKeys(depth=("obs", "depth"), z_uni="latent")
    net = make_perception("eph", cpu_cfg, keys)
    td = make_inputs(cpu_cfg)
    td["obs", "depth"] = td.pop("depth")
    assert net(td)["latent"].shape == (2, 32)


def test_paper_config_size_and_forward():
    cfg = perception_config("paper", proprio_dim=PROPRIO)
    assert cfg.io.image_size == 128
    assert cfg.vit.patch_size == 16
    net = make_perception("tcvit", cfg)
    n_params = sum(p.numel() for p in net.parameters())
    assert abs(n_params - 31.25e6) / 31.25e6 < 0.01, n_params  # paper: 31.25M
    with torch.no_grad():
        out = net(make_inputs(cfg, batch=(1,)))
    assert out["goals_uni"].shape == (1, 3, 2)


def test_config_validation_names_bad_field(cpu_cfg):
    bad = dataclasses.replace(cpu_cfg, eph_depth_cutoff=1.5)
    with pytest.raises(ValueError, match="eph_depth_cutoff"):
        make_perception("eph", bad)
    bad = dataclasses.replace(cpu_cfg, vit=dataclasses.replace(cpu_cfg.vit, heads=5))
    with pytest.raises(ValueError, match="heads 5"):
        make_perception("tcvit", bad)


def _first_layer_width(cfg, name):
    return cfg.rma_layers[0] if name.startswith("rma") else cfg.memory_in_layers[0]


@pytest.mark.parametrize("name", sorted(PERCEPTION_BUILDERS))
def test_no_waypoint_input_with_m_zero(cpu_cfg, name):
    """M = 0 (``num_waypoints=0``): no waypoint input, the key is never read, and the only
    parameter change is the first memory-input / RMA-trunk layer losing ``gps_dim`` inputs."""
    cfg0 = perception_config("cpu", proprio_dim=PROPRIO, num_waypoints=0)
    torch.manual_seed(0)
    net0 = make_perception(name, cfg0)
    net1 = make_perception(name, cpu_cfg)
    assert "waypoint_gps" not in net0.in_keys and "waypoint_gps" in net1.in_keys
    n0 = sum(p.numel() for p in net0.parameters())
    n1 = sum(p.numel() for p in net1.parameters())
    assert n1 - n0 == cpu_cfg.io.gps_dim * _first_layer_width(cpu_cfg, name)
    td = make_inputs(cfg0).exclude("waypoint_gps")
    out = net0(td)
    assert out["z_uni"].shape == (2, 32) and out["goals_uni"].shape == (2, 3, 2)
    # the output spec carries the config's sizes
    assert net0.spec["z_uni"].shape == (32,) and net0.spec["goals_uni"].shape == (3, 2)
    small = perception_config("cpu", proprio_dim=PROPRIO, latent_dim=7, num_goals=4, num_waypoints=0)
    spec = make_perception(name, small).spec
    assert spec["z_uni"].shape == (7,) and spec["goals_uni"].shape == (4, 2)
    assert spec["delta_g0"].shape == (2,)


def test_num_waypoints_is_zero_or_one():
    with pytest.raises(ValueError, match="num_waypoints must be 0 or 1, got 2"):
        perception_config("cpu", proprio_dim=PROPRIO, num_waypoints=2)


def test_committed_student_checkpoint_acts_as_before():
    """The default (M = 1) is LEGO-H's network: the RandomMix student
    (``checkpoints/student_h1_randommix.pt``) loads strictly and gives the actions it gave before
    ``num_waypoints`` existed (recorded with that code)."""
    from pathlib import Path

    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from legoh_rl.modules import LocomotionConfig, make_locomotion_actor

    path = Path(__file__).resolve().parents[1] / "checkpoints" / "student_h1_randommix.pt"
    ck = torch.load(path, map_location="cpu", weights_only=False)
    d = ck["meta"]["obs_layout"]["proprio"][0]
    cfg = perception_config("cpu", d, num_goals=3)
    assert cfg.io.num_waypoints == 1
    perception = make_perception("tcvit", cfg)
    perception.load_state_dict(ck["perception"], strict=True)
    actor = make_locomotion_actor(LocomotionConfig(proprio_dim=d, num_actions=10))
    actor.load_state_dict(ck["actor"], strict=True)

    def ramp(*shape):
        return torch.linspace(0.0, 1.0, torch.Size(shape).numel()).reshape(shape)

    td = TensorDict(
        {
            "depth_goal_stack": ramp(1, 4, 2, 64, 64), "depth": ramp(1, 1, 64, 64).flip(-1),
            "goal_gps": torch.tensor([[8.0, -3.0]]), "waypoint_gps": torch.tensor([[4.0, 1.5]]),
            "proprio": torch.sin(torch.arange(d, dtype=torch.float32)).unsqueeze(0) * 0.5,
            "is_init": torch.ones(1, 1, dtype=torch.bool),
        },
        [1],
    )
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        out = perception(td)
        out["goal_next"] = out["goals_uni"][..., 0, :]
        actor(out)
        # the memory input is still MLP(concat(gamma, goal_gps, waypoint_gps, proprio))
        mem = perception[1].module
        by_hand = mem.mlp(torch.cat([out["perception_features"], td["goal_gps"],
                                     td["waypoint_gps"], td["proprio"]], -1))
    assert torch.equal(out["perception_memory_in"], by_hand)
    before = [0.673367202, -0.146161661, 2.037792206, 3.133442640, -2.638010740, -0.902080297,
              -1.319347143, -0.183866873, -0.197534755, -5.711642742]
    torch.testing.assert_close(out["loc"][0], torch.tensor(before), rtol=0, atol=1e-4)
