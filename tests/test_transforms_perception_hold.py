"""PerceptionHold: per-world call counting, resets forcing a forward, recurrent state, training.

Uses `CounterPixelEnv` (tests/test_transforms_env.py): pixel value 1000 * world + steps since
reset, ``cam_tick`` every 5th step with a per-world phase, random partial terminations.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, InitTracker, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.modules import GRUModule

sys.path.insert(0, str(Path(__file__).parent))
from test_transforms_env import CounterPixelEnv  # noqa: E402

from legoh_rl.transforms import DepthHistory, PerceptionHold  # noqa: E402

SHAPES = {"z_uni": (4,), "delta_g0": (2,), "goals_uni": (3, 2)}


class CountingPerception(TensorDictModuleBase):
    """Fake TC-ViT: outputs are functions of the pixel value; records the worlds it ran on."""

    in_keys = ["pixels", "world_id"]
    out_keys = ["z_uni", "delta_g0", "goals_uni"]

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[torch.Tensor] = []

    def forward(self, td: TensorDict) -> TensorDict:
        self.calls.append(td["world_id"].reshape(-1).clone())
        v = td["pixels"].flatten(-3)[..., :1]  # (..., 1) pixel value
        td.set("z_uni", v.expand(*v.shape[:-1], 4) + torch.arange(4.0))
        td.set("delta_g0", torch.cat([v, -v], -1))
        td.set("goals_uni", (v.unsqueeze(-1) + torch.arange(6.0).view(3, 2)))
        return td


class ActionFromGoal(nn.Module):
    def forward(self, goal_next: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return torch.tanh(goal_next[..., :1] * 0 + z[..., :1] * 0)


def action_head() -> TensorDictModule:
    return TensorDictModule(ActionFromGoal(), in_keys=["goal_next", "z_uni"], out_keys=["action"])


def make(batch=5, p_term=0.0, seed=0, perception=None, **hold_kwargs):
    perception = CountingPerception() if perception is None else perception
    hold = PerceptionHold(perception, tick_key="cam_tick", out_shapes=SHAPES, **hold_kwargs)
    env = TransformedEnv(
        CounterPixelEnv(batch=batch, p_term=p_term, seed=seed),
        Compose(InitTracker(), hold.make_tensordict_primer()),
    )
    env.set_seed(seed)
    return env, hold, TensorDictSequential(hold, action_head())


def calls_per_world(perception: CountingPerception, batch: int) -> torch.Tensor:
    ids = torch.cat(perception.calls) if perception.calls else torch.zeros(0, dtype=torch.long)
    return torch.bincount(ids, minlength=batch)


def pixel(td: TensorDict) -> torch.Tensor:
    return td["pixels"].flatten(-3)[..., 0]


def expected_held(ro: TensorDict, tick: torch.Tensor) -> torch.Tensor:
    """Pixel value at the last effective tick step <= t, per world."""
    pix = pixel(ro)
    out = torch.empty_like(pix)
    for w in range(pix.shape[0]):
        cur = None
        for t in range(pix.shape[1]):
            if tick[w, t]:
                cur = pix[w, t]
            out[w, t] = cur
    return out


def test_one_forward_per_five_steps_per_world() -> None:
    env, hold, policy = make(batch=5)
    perception = hold.perception
    with torch.no_grad():
        ro = env.rollout(50, policy)
    counts = calls_per_world(perception, 5)
    # world w ticks when (count + w) % 5 == 0: 10 ticks in 50 steps; worlds 1..4 also get
    # the forced forward on their reset step (not a tick for them)
    assert counts.tolist() == [10, 11, 11, 11, 11]
    # every call ran on the ticking worlds only
    tick = ro["cam_tick"][..., 0] | ro["is_init"][..., 0]
    sizes = [len(c) for c in perception.calls]
    assert sizes == [int(n) for n in tick.sum(0) if n > 0]
    assert sum(sizes) == int(tick.sum()) < 50 * 5 / 4
    # latent tiling: outputs are those of the last tick; nearest-goal forwarding: row 0
    held = expected_held(ro, tick)
    torch.testing.assert_close(ro["z_uni"][..., 0], held)
    torch.testing.assert_close(ro["goal_next"], ro["goals_uni"][..., 0, :])
    torch.testing.assert_close(ro["goal_next"], torch.stack([held, held + 1], -1))
    assert torch.equal(ro["next", "held_z_uni"], ro["z_uni"])


def test_partial_resets_force_a_forward() -> None:
    env, hold, policy = make(batch=6, p_term=0.06, seed=2)
    perception = hold.perception
    with torch.no_grad():
        ro = env.rollout(100, policy, break_when_any_done=False)
    init = ro["is_init"][..., 0]
    tick = ro["cam_tick"][..., 0]
    assert init[:, 1:].any() and (init & ~tick)[:, 1:].any(), "need resets off the tick"
    eff = tick | init
    counts = calls_per_world(perception, 6)
    assert counts.tolist() == eff.sum(1).tolist()
    # in any 5 consecutive control steps without a reset inside, at most one forward
    win_eff = eff.unfold(1, 5, 1).sum(-1)
    win_reset = init.unfold(1, 5, 1).any(-1)
    assert (win_eff[~win_reset] <= 1).all() and (win_eff[~win_reset] == 1).any()
    torch.testing.assert_close(ro["z_uni"][..., 0], expected_held(ro, eff))
    # no value leaks across a reset: right after a reset the output is the reset frame's
    torch.testing.assert_close(ro["z_uni"][..., 0][init], pixel(ro)[init])


def test_collector_auto_registers_primer_and_holds() -> None:
    """torchrl's Collector finds PerceptionHold.make_tensordict_primer() by itself."""
    perception = CountingPerception()
    hold = PerceptionHold(perception, tick_key="cam_tick", out_shapes=SHAPES)
    env = TransformedEnv(CounterPixelEnv(batch=4, p_term=0.05, seed=4), InitTracker())
    policy = TensorDictSequential(hold, action_head())
    collector = Collector(
        env, policy, frames_per_batch=4 * 25, total_frames=4 * 50,
        auto_register_policy_transforms=True,
    )
    perception.calls.clear()  # the Collector dry-runs the policy once at construction
    batches = [b.clone() for b in collector]
    collector.shutdown()
    data = torch.cat(batches, 1)  # [4, 50]
    assert "held_z_uni" in data.keys()
    eff = data["cam_tick"][..., 0] | data["is_init"][..., 0]
    assert eff.sum() < data.numel() / 3  # ticks every 5th step, plus the resets
    assert calls_per_world(perception, 4).tolist() == eff.sum(1).tolist()
    torch.testing.assert_close(data["z_uni"][..., 0], expected_held(data, eff))


def test_check_env_specs_with_primer_and_output_spec() -> None:
    env, hold, _ = make(batch=3)
    env.append_transform(DepthHistory(in_key="pixels", out_key="stack", tick_key="cam_tick"))
    check_env_specs(env)
    assert env.observation_spec["held_goals_uni"].shape == (3, 3, 2)
    spec = hold.output_spec((3,))
    assert spec["goal_next"].shape == (3, 2) and spec["z_uni"].shape == (3, 4)
    # the default shapes follow docs/keys.md
    default = PerceptionHold(CountingPerception())
    assert default.output_spec()["z_uni"].shape == (32,)
    assert default.held_spec()["held_goals_uni"].shape == (3, 2)
    assert "perception_tick" in default.in_keys and "is_init" in default.in_keys


def test_hold_forward_matches_acting_non_recurrent() -> None:
    env, hold, policy = make(batch=4, p_term=0.05, seed=6)
    with torch.no_grad():
        ro = env.rollout(60, policy, break_when_any_done=False)
    perception = hold.perception
    perception.calls.clear()
    data = ro.exclude("z_uni", "delta_g0", "goals_uni", "goal_next")
    hold.hold_forward(data)
    for key in ("z_uni", "delta_g0", "goals_uni", "goal_next"):
        torch.testing.assert_close(data[key], ro[key])
    eff = ro["cam_tick"][..., 0] | ro["is_init"][..., 0]
    assert len(perception.calls) == 1 and len(perception.calls[0]) == int(eff.sum())
    # a slice starting between ticks uses the stored held values before its first tick
    part = ro[:, 7:].exclude("z_uni", "delta_g0", "goals_uni", "goal_next")
    hold.hold_forward(part)
    torch.testing.assert_close(part["z_uni"], ro["z_uni"][:, 7:])


class Heads(nn.Module):
    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.lin = nn.Linear(hidden, 4 + 2 + 6)

    def forward(self, emb: torch.Tensor):
        out = self.lin(emb)
        return out[..., :4], out[..., 4:6], out[..., 6:].unflatten(-1, (3, 2))


def gru_perception(hidden: int = 8) -> TensorDictSequential:
    torch.manual_seed(0)
    feat = TensorDictModule(
        lambda p: p.flatten(-3)[..., :4] / 1000.0, in_keys=["pixels"], out_keys=["feat"]
    )
    gru = GRUModule(
        input_size=4, hidden_size=hidden, in_keys=["feat", "rs", "is_init"],
        out_keys=["emb", ("next", "rs")],
    )
    heads = TensorDictModule(Heads(hidden), in_keys=["emb"], out_keys=list(SHAPES))
    return TensorDictSequential(feat, gru, heads)


def test_recurrent_state_advances_only_on_ticks_and_training_matches() -> None:
    perception = gru_perception()
    env, hold, policy = make(batch=4, p_term=0.05, seed=8, perception=perception)
    assert hold.recurrent_keys == ["rs"]
    env.append_transform(perception[1].make_tensordict_primer())
    with torch.no_grad():
        ro = env.rollout(60, policy, break_when_any_done=False)
    eff = ro["cam_tick"][..., 0] | ro["is_init"][..., 0]
    same = (ro["next", "rs"] == ro["rs"]).flatten(-2).all(-1)
    assert torch.equal(same, ~eff), "hidden state must change exactly on effective ticks"

    # reference: a plain GRU run per world over the tick steps only, reset on is_init
    gru = perception[1]
    for w in range(4):
        h = torch.zeros(1, 1, 8)
        for t in range(60):
            if ro["is_init"][w, t, 0]:
                h = torch.zeros(1, 1, 8)
            if eff[w, t]:
                x = ro["pixels"][w, t].flatten()[:4].view(1, 1, 4) / 1000.0
                _, h = gru.gru(x, h)
            torch.testing.assert_close(ro["next", "rs"][w, t], h[:, 0], rtol=1e-5, atol=1e-6)

    # training: recompute with gradients on tick steps only, compacted per row
    data = ro.exclude("z_uni", "delta_g0", "goals_uni", "goal_next", "emb", "feat")
    hold.hold_forward(data)
    for key in ("z_uni", "delta_g0", "goals_uni", "goal_next"):
        torch.testing.assert_close(data[key], ro[key], rtol=1e-5, atol=1e-5)
    data["z_uni"].sum().backward()
    grads = [p.grad for p in gru.parameters()]
    assert all(g is not None and g.abs().sum() > 0 for g in grads)


def test_no_primer_warns_and_runs_every_step() -> None:
    perception = CountingPerception()
    hold = PerceptionHold(perception, tick_key="cam_tick", out_shapes=SHAPES)
    env = TransformedEnv(CounterPixelEnv(batch=3), InitTracker())
    policy = TensorDictSequential(hold, action_head())
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        with torch.no_grad():
            env.rollout(10, policy)
    assert any("make_tensordict_primer" in str(w.message) for w in rec)
    assert calls_per_world(perception, 3).tolist() == [10, 10, 10]


def test_errors() -> None:
    with pytest.raises(ValueError, match=r"hold_keys \['latent'\] are not among"):
        PerceptionHold(CountingPerception(), hold_keys=["latent", "goals_uni"])
    with pytest.raises(ValueError, match="goals_key 'goals' must be one of"):
        PerceptionHold(CountingPerception(), goals_key="goals")
    with pytest.raises(TypeError, match="TensorDictModuleBase"):
        PerceptionHold(nn.Linear(2, 2))
    hold = PerceptionHold(CountingPerception(), hold_keys=["z_uni", "goals_uni"],
                          out_shapes={"z_uni": (7,)})
    td = TensorDict(
        {
            "pixels": torch.ones(2, 1, 4, 4), "world_id": torch.zeros(2, 1, dtype=torch.long),
            "perception_tick": torch.tensor([[True], [False]]),
            "held_z_uni": torch.zeros(2, 7), "held_goals_uni": torch.zeros(2, 3, 2),
            "held_valid": torch.ones(2, 1, dtype=torch.bool),
        },
        [2],
    )
    with pytest.raises(ValueError, match=r"wrote 'z_uni' with feature shape \(4,\), but the held "
                       r"shape is \(7,\) \(from out_shapes\)"):
        hold(td)
    with pytest.raises(ValueError, match="time dimension"):
        hold.hold_forward(td[0])


class SpecPerception(CountingPerception):
    """CountingPerception declaring its outputs through torchrl's ``spec`` attribute."""

    def __init__(self, batch: tuple = ()) -> None:
        super().__init__()
        self.spec = Composite(
            {k: Unbounded(shape=(*batch, *v)) for k, v in SHAPES.items()}, shape=batch
        )


def example_td(batch: int = 2) -> TensorDict:
    return TensorDict(
        {"pixels": torch.ones(batch, 1, 4, 4), "world_id": torch.zeros(batch, 1, dtype=torch.long)},
        [batch],
    )


def test_held_shapes_from_the_module_spec_or_a_dry_run() -> None:
    # the module's spec (feature shapes after the Composite's own batch shape)
    for batch in ((), (3,)):
        hold = PerceptionHold(SpecPerception(batch), tick_key="cam_tick")
        assert hold.out_shapes == SHAPES
        assert set(hold.shape_sources.values()) == {"the perception module's spec"}
        assert hold.held_spec()["held_z_uni"].shape == (4,)
    # a dry run on an example TensorDict or on a spec of the inputs
    perception = CountingPerception()
    hold = PerceptionHold(perception, example_input=example_td())
    assert hold.out_shapes == SHAPES and hold.shape_sources["goals_uni"] == "the dry run on example_input"
    assert len(perception.calls) == 1  # one forward, on a copy
    spec = Composite(
        pixels=Unbounded(shape=(5, 1, 4, 4)), world_id=Unbounded(shape=(5, 1), dtype=torch.long),
        shape=(5,),
    )
    assert PerceptionHold(CountingPerception(), example_input=spec).out_shapes == SHAPES
    # nothing known: LEGO-H's defaults, and the first forward says what is wrong
    hold = PerceptionHold(CountingPerception())
    assert hold.out_shapes == {"z_uni": (32,), "delta_g0": (2,), "goals_uni": (3, 2)}
    with pytest.raises(ValueError, match=r"wrote 'z_uni' with feature shape \(4,\), but the held "
                       r"shape is \(32,\) \(from LEGO-H's default shapes"):
        hold(example_td())


def test_explicit_out_shapes_are_checked_against_the_module() -> None:
    ok = PerceptionHold(SpecPerception(), out_shapes=SHAPES)
    assert ok.shape_sources["z_uni"] == "out_shapes"
    with pytest.raises(ValueError, match=r"held shape of 'z_uni': the perception module's spec "
                       r"gives \(4,\) but out_shapes gives \(32,\)"):
        PerceptionHold(SpecPerception(), out_shapes={"z_uni": (32,)})
    with pytest.raises(ValueError, match=r"held shape of 'goals_uni': the dry run on example_input "
                       r"gives \(3, 2\) but out_shapes gives \(5, 2\)"):
        PerceptionHold(CountingPerception(), out_shapes={"goals_uni": (5, 2)}, example_input=example_td())
    with pytest.raises(RuntimeError, match="dry run of the perception module on example_input failed"):
        PerceptionHold(CountingPerception(), example_input=TensorDict({"pixels": torch.ones(2, 1, 4, 4)}, [2]))


class CountingEncoder(nn.Module):
    """A learnable encoder (pixels -> 4 features) that records how many samples it ran on."""

    out_dim = 4

    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(4, 4)
        self.sizes: list[int] = []

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        self.sizes.append(pixels.shape[:-3].numel())
        return self.lin(pixels.flatten(-3)[..., :4] / 1000.0)


def encoder_gru_perception(hidden: int = 8) -> TensorDictSequential:
    torch.manual_seed(0)
    enc = TensorDictModule(CountingEncoder(), in_keys=["pixels"], out_keys=["feat"])
    gru = GRUModule(input_size=4, hidden_size=hidden, in_keys=["feat", "rs", "is_init"],
                    out_keys=["emb", ("next", "rs")])
    heads = TensorDictModule(Heads(hidden), in_keys=["emb"], out_keys=list(SHAPES))
    return TensorDictSequential(enc, gru, heads)


def test_recorded_features_let_training_run_the_encoder_on_a_fraction_of_the_ticks() -> None:
    perception = encoder_gru_perception()
    encoder = perception[0].module
    env, hold, policy = make(batch=4, p_term=0.05, seed=8, perception=perception, feature_key="feat")
    assert hold.feature_shape == (4,) and "feat" in hold.out_keys
    env.append_transform(perception[1].make_tensordict_primer())
    with torch.no_grad():
        ro = env.rollout(60, policy, break_when_any_done=False)
    eff = ro["cam_tick"][..., 0] | ro["is_init"][..., 0]
    # acting records the encoder's output on the ticking worlds, zeros elsewhere
    fresh = encoder(ro["pixels"])
    torch.testing.assert_close(ro["feat"][eff], fresh[eff])
    assert torch.equal(ro["feat"][~eff], torch.zeros_like(ro["feat"][~eff]))
    assert not ro["feat"].requires_grad

    drop = ("z_uni", "delta_g0", "goals_uni", "goal_next", "emb")
    full = ro.exclude(*drop, "feat")
    encoder.sizes.clear()
    hold.hold_forward(full)
    padded = 4 * int(eff.sum(1).max())  # the ticks compacted per row, short rows padded
    assert encoder.sizes == [padded]  # without recorded features: every tick

    torch.manual_seed(3)
    part = ro.exclude(*drop)
    encoder.sizes.clear()
    hold.hold_forward(part, encoder_grad_fraction=0.5)
    assert len(encoder.sizes) == 1 and 0 < encoder.sizes[0] < padded
    # the weights have not moved since acting: recorded and recomputed features agree
    for key in ("z_uni", "delta_g0", "goals_uni", "goal_next"):
        torch.testing.assert_close(part[key], full[key], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(part[key], ro[key], rtol=1e-5, atol=1e-5)
    part["z_uni"].sum().backward()
    assert encoder.lin.weight.grad is not None and encoder.lin.weight.grad.abs().sum() > 0
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in perception[1].parameters())

    # moved encoder weights: the ticks it skipped keep the recorded (acting) features
    with torch.no_grad():
        encoder.lin.weight.add_(1.0)
    encoder.sizes.clear()
    tiny = ro.exclude(*drop)
    hold.hold_forward(tiny, encoder_grad_fraction=1e-12)  # no tick drawn: the encoder does not run
    assert encoder.sizes == []
    torch.testing.assert_close(tiny["z_uni"], ro["z_uni"], rtol=1e-5, atol=1e-5)
    moved = ro.exclude(*drop)
    hold.hold_forward(moved, encoder_grad_fraction=1.0)  # fraction 1: every tick, the new weights
    assert not torch.allclose(moved["z_uni"], ro["z_uni"])


def test_recorded_features_errors() -> None:
    perception = encoder_gru_perception()
    env, hold, policy = make(batch=2, perception=perception, feature_key="feat")
    env.append_transform(perception[1].make_tensordict_primer())
    with torch.no_grad():
        ro = env.rollout(6, policy)
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="encoder_grad_fraction"):
            hold.hold_forward(ro.clone(), encoder_grad_fraction=bad)
    with pytest.raises(ValueError, match="feature_key='emb'"):
        PerceptionHold(encoder_gru_perception(), tick_key="cam_tick", out_shapes=SHAPES, feature_key="emb")
    with pytest.raises(ValueError, match="TensorDictSequential"):
        PerceptionHold(CountingPerception(), tick_key="cam_tick", out_shapes=SHAPES, feature_key="z_uni")
    no_width = encoder_gru_perception()
    del CountingEncoder.out_dim
    try:
        with pytest.raises(ValueError, match="out_dim"):
            PerceptionHold(no_width, tick_key="cam_tick", out_shapes=SHAPES, feature_key="feat")
    finally:
        CountingEncoder.out_dim = 4
