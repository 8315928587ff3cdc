"""The TorchRL anchors composed on a foreign env with non-default sizes (docs/keys.md, "Reuse").

``TinyCamEnv`` (below) is not the hiking env: its own key names (``cam``, ``target``,
``obs``, ``cam_tick``), a 32x32 depth image, a camera tick every 3rd step (per-world phase),
5-dim proprioception, 3 actions, partial resets, and **no waypoint**. On it:

* TC-ViT with M = 0 waypoints (``PerceptionIO(num_waypoints=0)``), 3 frames, 2 goals, an
  8-dim latent, renamed keys;
* ``PerceptionHold`` *without* ``out_shapes`` (it reads TC-ViT's output spec);
* a locomotion actor reading the held outputs, collected by ``env.rollout`` and a
  ``Collector``;
* every LEGO-H loss and torchrl's ``ClipPPOLoss`` on the split batch with their default
  keys (the valid-step mask ``("collector", "mask")``).
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.collectors.utils import split_trajectories
from torchrl.data import Binary, Composite, Unbounded
from torchrl.envs import Compose, EnvBase, InitTracker, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.modules import MLP, ValueOperator
from torchrl.modules.utils import get_primers_from_module

from legoh_rl.modules import (
    DepthCNNConfig,
    LocomotionConfig,
    LocomotionKeys,
    PerceptionConfig,
    PerceptionIO,
    PerceptionKeys,
    ViViTConfig,
    make_locomotion_actor,
    make_tcvit,
)
from legoh_rl.modules.masked_vae import MaskedVAEConfig
from legoh_rl.objectives import (
    VALID_MASK_KEY,
    DAggerLoss,
    HLMLoss,
    MaskedVAELoss,
    make_ppo_loss,
    policy_kl,
)
from legoh_rl.transforms import DepthHistory, GoalTiling, PerceptionHold

B, SIZE, D, A = 3, 32, 5, 3
LATENT, GOALS, FRAMES, PERIOD = 8, 2, 3, 3
HELD = ("z_uni", "delta_g0", "goals_uni")


class TinyCamEnv(EnvBase):
    """``cam`` (1, 32, 32) random depth in [0, 1], ``target`` (2,), ``obs`` (5,), ``cam_tick``.

    ``cam_tick`` is True when ``(count + world) % 3 == 0``; world ``w`` terminates after
    ``7 + 2 w`` steps (partial resets, mostly off the tick).
    """

    def __init__(self, seed: int = 0) -> None:
        super().__init__(batch_size=torch.Size([B]))
        self.observation_spec = Composite(
            cam=Unbounded(shape=(B, 1, SIZE, SIZE)),
            target=Unbounded(shape=(B, 2)),
            obs=Unbounded(shape=(B, D)),
            cam_tick=Binary(n=1, shape=(B, 1), dtype=torch.bool),
            shape=(B,),
        )
        self.action_spec = Unbounded(shape=(B, A))
        self.reward_spec = Unbounded(shape=(B, 1))
        self.full_done_spec = Composite(
            done=Binary(n=1, shape=(B, 1), dtype=torch.bool),
            terminated=Binary(n=1, shape=(B, 1), dtype=torch.bool),
            shape=(B,),
        )
        self.count = torch.zeros(B, 1, dtype=torch.int64)
        self.world = torch.arange(B).unsqueeze(-1)
        self.target = torch.zeros(B, 2)
        self.rng = torch.Generator().manual_seed(seed)

    def _set_seed(self, seed: int | None) -> None:
        self.rng.manual_seed(0 if seed is None else seed)

    def _obs(self) -> TensorDict:
        return TensorDict(
            {
                "cam": torch.rand(B, 1, SIZE, SIZE, generator=self.rng),
                "target": self.target.clone(),
                "obs": torch.randn(B, D, generator=self.rng),
                "cam_tick": (self.count + self.world) % PERIOD == 0,
            },
            batch_size=self.batch_size,
        )

    def _reset(self, tensordict: TensorDict | None = None, **kwargs) -> TensorDict:
        mask = torch.ones(B, dtype=torch.bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(B)
        self.count[mask] = 0
        self.target[mask] = torch.randn(int(mask.sum()), 2, generator=self.rng) * 10.0
        td = self._obs()
        td.set("done", torch.zeros(B, 1, dtype=torch.bool))
        td.set("terminated", torch.zeros(B, 1, dtype=torch.bool))
        return td

    def _step(self, tensordict: TensorDict) -> TensorDict:
        self.count += 1
        term = self.count >= 7 + 2 * self.world
        td = self._obs()
        td.set("reward", -tensordict["action"].pow(2).sum(-1, keepdim=True))
        td.set("done", term.clone())
        td.set("terminated", term.clone())
        return td


class EncoderCalls:
    """Forward hook on TC-ViT's visual encoder: the number of samples it encoded."""

    def __init__(self, module: nn.Module) -> None:
        self.rows = 0
        module.register_forward_hook(self)

    def __call__(self, module, args, output) -> None:
        self.rows += output.shape[:-1].numel()


def build(seed: int = 0):
    torch.manual_seed(seed)
    io = PerceptionIO(proprio_dim=D, image_size=SIZE, num_frames=FRAMES, num_goals=GOALS,
                      latent_dim=LATENT, num_waypoints=0)
    cfg = PerceptionConfig(
        io=io,
        vit=ViViTConfig(patch_size=8, dim=16, heads=2, layers=1),
        cnn=DepthCNNConfig(channels=(4, 8), kernel_sizes=(3, 3), strides=(2, 2), out_dim=16),
        fusion_layers=(32, 16),
        memory_in_layers=(32,),
        gru_hidden=16,
    )
    keys = PerceptionKeys(depth="cam", depth_goal_stack="cam_goal_stack", goal_gps="target",
                          proprio="obs")
    perception = make_tcvit(cfg, keys)
    hold = PerceptionHold(perception, tick_key="cam_tick")  # no out_shapes
    actor = make_locomotion_actor(
        LocomotionConfig(proprio_dim=D, num_actions=A, latent_dim=LATENT, layers=(32,)),
        LocomotionKeys(proprio="obs"),
    )
    critic = ValueOperator(MLP(in_features=D + 2, out_features=1, num_cells=[16]),
                           in_keys=["obs", "target"])

    env = TransformedEnv(
        TinyCamEnv(seed),
        Compose(
            InitTracker(),
            DepthHistory(history=2 * FRAMES, stride=2, in_key="cam", out_key="cam_stack",
                         tick_key="cam_tick"),
            GoalTiling("target", stack_key="cam_stack", out_key="cam_goal_stack"),
        ),
    )
    env.append_transform(get_primers_from_module(perception))  # GRU hidden state
    env.append_transform(hold.make_tensordict_primer())  # held outputs
    env.set_seed(seed)
    policy = TensorDictSequential(hold, actor)
    return env, perception, hold, actor, critic, policy


def effective_tick(td: TensorDict) -> torch.Tensor:
    return td["cam_tick"][..., 0] | td["is_init"][..., 0]


def check_held_and_recomputed(ro: TensorDict, perception) -> None:
    """Non-tick steps repeat the previous step's outputs; tick steps are fresh forwards."""
    eff = effective_tick(ro)
    assert eff[:, 0].all()
    for t in range(ro.shape[1]):
        step = ro[:, t]
        fresh = perception(step.select(*perception.in_keys).clone())
        for w in range(B):
            for k in HELD:
                if eff[w, t]:
                    torch.testing.assert_close(step[k][w], fresh[k][w], rtol=1e-5, atol=1e-5)
                else:
                    assert torch.equal(step[k][w], ro[w, t - 1][k]), (k, w, t)
    # a non-tick step's inputs differ, so a fresh forward would differ: the values were held
    non_tick = ~eff
    fresh_all = perception(ro.select(*perception.in_keys).reshape(-1).clone()).reshape(ro.shape)
    gap = (fresh_all["z_uni"] - ro["z_uni"]).abs().amax(-1)
    assert (gap[non_tick] > 1e-3).all()
    torch.testing.assert_close(ro["goal_next"], ro["goals_uni"][..., 0, :])


def test_rollout_tcvit_without_waypoint_held_without_out_shapes() -> None:
    env, perception, hold, actor, _, policy = build()
    check_env_specs(env)
    # M = 0: TC-ViT neither reads nor needs a waypoint; the env has none
    assert "waypoint_gps" not in perception.in_keys and "waypoint_gps" not in hold.in_keys
    assert "waypoint_gps" not in env.observation_spec.keys(True)
    # held shapes come from TC-ViT's spec (its config), not from LEGO-H's defaults
    assert hold.out_shapes == {"z_uni": (LATENT,), "delta_g0": (2,), "goals_uni": (GOALS, 2)}
    assert set(hold.shape_sources.values()) == {"the perception module's spec"}
    assert env.observation_spec["held_goals_uni"].shape == (B, GOALS, 2)

    calls = EncoderCalls(perception[0].module)
    steps = 24
    with torch.no_grad():
        ro = env.rollout(steps, policy, break_when_any_done=False)
    assert ro.shape == (B, steps)
    assert ro["cam_goal_stack"].shape == (B, steps, FRAMES, 2, SIZE, SIZE)
    assert ro["z_uni"].shape == (B, steps, LATENT) and ro["held_z_uni"].shape == (B, steps, LATENT)
    assert ro["goals_uni"].shape == (B, steps, GOALS, 2)
    assert ro["delta_g0"].shape == ro["goal_next"].shape == (B, steps, 2)
    assert ro["loc"].shape == ro["action"].shape == (B, steps, A)
    assert ro["perception_hidden"].shape == (B, steps, 1, 16)

    eff = effective_tick(ro)
    init = ro["is_init"][..., 0]
    assert (init & ~ro["cam_tick"][..., 0])[:, 1:].any(), "need resets off the tick"
    assert 0 < eff.sum() < ro.numel() / 2
    assert calls.rows == int(eff.sum())  # TC-ViT ran on the ticking worlds only
    # the GRU state advances exactly on the effective ticks
    same = (ro["next", "perception_hidden"] == ro["perception_hidden"]).flatten(-2).all(-1)
    assert torch.equal(same, ~eff)
    with torch.no_grad():
        check_held_and_recomputed(ro, perception)


def test_collector_batch_feeds_every_loss_with_default_keys() -> None:
    env, perception, hold, actor, critic, policy = build(seed=1)
    steps = 20
    collector = Collector(env, policy, frames_per_batch=B * steps, total_frames=B * steps)
    batch = next(iter(collector)).clone()
    collector.shutdown()
    assert batch.shape == (B, steps)
    assert VALID_MASK_KEY not in batch.keys(True)  # an unsplit batch: every step counts
    with torch.no_grad():
        check_held_and_recomputed(batch, perception)
        # training recomputes exactly what the policy held while acting
        again = hold.hold_forward(batch.exclude(*HELD, "goal_next"))
    for k in (*HELD, "goal_next"):
        torch.testing.assert_close(again[k], batch[k], rtol=1e-5, atol=1e-5)

    loss_ppo, gae = make_ppo_loss(actor, critic)
    with torch.no_grad():
        gae(batch)
    # teacher labels as a distillation recipe would fill them
    g = torch.Generator().manual_seed(0)
    batch["z_tea"] = torch.tanh(torch.randn(B, steps, LATENT, generator=g))
    batch["goals_tea"] = nn.functional.normalize(torch.randn(B, steps, GOALS, 2, generator=g), dim=-1)
    batch["action_tea"] = torch.randn(B, steps, A, generator=g)

    data = split_trajectories(batch)  # [num_trajs, max_len] + ("collector", "mask")
    valid = data[VALID_MASK_KEY]
    valid = valid.reshape(data.shape)
    assert (~valid).any() and valid.sum() == B * steps
    # garbage on the padded steps: a loss that ignored the mask would see it
    for k in ("z_tea", "goals_tea", "action_tea"):
        data[k][~valid] = 1e6

    for loss in (DAggerLoss(), HLMLoss(MaskedVAELoss(MaskedVAEConfig(action_dim=A))), MaskedVAELoss()):
        assert loss.tensor_keys.mask == VALID_MASK_KEY
    im = DAggerLoss()(data)
    v = data[valid]
    expected = {
        "latent": (v["z_tea"] - v["z_uni"]).pow(2).sum(-1).mean(),
        "goals": nn.functional.smooth_l1_loss(v["goals_uni"], v["goals_tea"]),
        "action": nn.functional.smooth_l1_loss(v["loc"], v["action_tea"]),
    }
    for name, value in expected.items():
        torch.testing.assert_close(im[f"loss_im_{name}"], value)

    vae_loss = MaskedVAELoss(MaskedVAEConfig(action_dim=A), seed=0)
    rec = vae_loss(data)
    assert all(torch.isfinite(rec[k]) for k in rec.keys())
    hi = v["action_tea"].abs().max()
    assert vae_loss.vae.bounds_fitted and vae_loss.vae.action_high.abs().max() < 2 * hi + 1
    hie = HLMLoss(vae_loss, seed=0, reduction="none")(data)
    assert hie["loss_hlm_ts"].shape == valid.shape
    assert torch.isfinite(hie["loss_hlm_ts"]).all()
    assert (hie["loss_hlm_ts"][~valid] == 0).all() and (hie["loss_hlm_ts"][valid] > 0).any()

    out = loss_ppo(data)
    assert all(torch.isfinite(out[k]) for k in ("loss_objective", "loss_critic", "loss_entropy"))
    assert policy_kl(actor, data).item() == pytest.approx(0.0, abs=1e-6)
