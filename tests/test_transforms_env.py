"""DepthHistory and GoalTiling on a small batched TorchRL pixel env written here.

`CounterPixelEnv` has its own keys (``pixels``, ``target``, ``cam_tick``, ``count``,
``world_id``): the transforms are configured for them, which proves they do not depend on
the hiking env. The pixel value of world ``w`` at step ``c`` since its reset is
``1000 * w + c`` (a per-world counter), so stacks can be checked by hand.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import (
    Binary,
    Bounded,
    Composite,
    LazyTensorStorage,
    ReplayBuffer,
    Unbounded,
)
from torchrl.envs import CatFrames, Compose, EnvBase, InitTracker, TransformedEnv
from torchrl.envs.utils import check_env_specs

from legoh_rl.transforms import DepthHistory, GoalTiling

OFFSETS = (12, 8, 4, 0)


class CounterPixelEnv(EnvBase):
    """Batched toy env: ``pixels`` (1, H, W) or (H, W) = 1000 * world + steps since reset.

    ``cam_tick`` (1,) bool is True when ``(count + world) % period == 0`` (so most worlds do
    *not* tick on their reset step); ``target`` (2,) is a random goal drawn at reset;
    ``p_term`` is the per-step termination probability (partial resets).
    """

    def __init__(
        self,
        batch: int = 4,
        size: int = 8,
        *,
        with_tick: bool = True,
        period: int = 5,
        p_term: float = 0.0,
        channel: bool = True,
        seed: int = 0,
    ) -> None:
        super().__init__(batch_size=torch.Size([batch]))
        self.size, self.with_tick, self.period, self.p_term = size, with_tick, period, p_term
        self.channel = channel
        pix_shape = (batch, 1, size, size) if channel else (batch, size, size)
        obs = {
            "pixels": Bounded(low=0.0, high=1e6, shape=pix_shape),
            "target": Unbounded(shape=(batch, 2)),
            "count": Unbounded(shape=(batch, 1), dtype=torch.int64),
            "world_id": Unbounded(shape=(batch, 1), dtype=torch.int64),
        }
        if with_tick:
            obs["cam_tick"] = Binary(n=1, shape=(batch, 1), dtype=torch.bool)
        self.observation_spec = Composite(obs, shape=(batch,))
        self.action_spec = Bounded(low=-1.0, high=1.0, shape=(batch, 1))
        self.reward_spec = Unbounded(shape=(batch, 1))
        self.full_done_spec = Composite(
            done=Binary(n=1, shape=(batch, 1), dtype=torch.bool),
            terminated=Binary(n=1, shape=(batch, 1), dtype=torch.bool),
            shape=(batch,),
        )
        self.count = torch.zeros(batch, 1, dtype=torch.int64)
        self.target = torch.zeros(batch, 2)
        self.world = torch.arange(batch).unsqueeze(-1)
        self.rng = torch.Generator().manual_seed(seed)

    def _set_seed(self, seed: int | None) -> None:
        self.rng.manual_seed(0 if seed is None else seed)

    def _obs(self) -> TensorDict:
        b = self.batch_size[0]
        value = (1000 * self.world + self.count).float()  # (B, 1)
        shape = (b, 1, self.size, self.size) if self.channel else (b, self.size, self.size)
        pixels = value.reshape(b, *([1] * (len(shape) - 1))).expand(shape).clone()
        out = {
            "pixels": pixels,
            "target": self.target.clone(),
            "count": self.count.clone(),
            "world_id": self.world.clone(),
        }
        if self.with_tick:
            out["cam_tick"] = (self.count + self.world) % self.period == 0
        return TensorDict(out, batch_size=self.batch_size)

    def _reset(self, tensordict: TensorDict | None = None, **kwargs) -> TensorDict:
        b = self.batch_size[0]
        mask = torch.ones(b, dtype=torch.bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(b)
        self.count[mask] = 0
        self.target[mask] = torch.randn(int(mask.sum()), 2, generator=self.rng) * 20.0
        td = self._obs()
        td.set("done", torch.zeros(b, 1, dtype=torch.bool))
        td.set("terminated", torch.zeros(b, 1, dtype=torch.bool))
        return td

    def _step(self, tensordict: TensorDict) -> TensorDict:
        b = self.batch_size[0]
        self.count += 1
        term = torch.rand(b, 1, generator=self.rng) < self.p_term
        td = self._obs()
        td.set("reward", tensordict.get("action").clone())
        td.set("done", term.clone())
        td.set("terminated", term)
        return td


def reference_stacks(rollout: TensorDict, with_tick: bool) -> torch.Tensor:
    """Hand reference: per world, the frames that entered since reset; pick 12/8/4/0 back."""
    pix = rollout["next", "pixels"][..., 0, 0].flatten(2)[..., 0]  # (B, T): pixel value
    count = rollout["next", "count"][..., 0]
    tick = rollout["next", "cam_tick"][..., 0] if with_tick else torch.ones_like(count, dtype=torch.bool)
    root_pix = rollout["pixels"][..., 0, 0].flatten(2)[..., 0]
    b, t = pix.shape
    out = torch.zeros(b, t, 4)
    for w in range(b):
        entered = [root_pix[w, 0].item()]
        for s in range(t):
            if s > 0 and rollout["is_init"][w, s, 0]:
                entered = [root_pix[w, s].item()]  # new episode: reset frame
            if count[w, s] == 0:
                raise AssertionError("next obs never has count 0")
            if tick[w, s]:
                entered.append(pix[w, s].item())
            out[w, s] = torch.tensor([entered[max(len(entered) - 1 - o, 0)] for o in OFFSETS])
    return out


def pixel_stack_values(stack: torch.Tensor) -> torch.Tensor:
    """(..., 4, H, W) constant frames -> (..., 4) values; checks frames are constant."""
    flat = stack.flatten(-2)
    assert torch.equal(flat, flat[..., :1].expand_as(flat))
    return flat[..., 0]


def make_env(**kwargs) -> TransformedEnv:
    base = CounterPixelEnv(**kwargs)
    tick_key = "cam_tick" if base.with_tick else None
    return TransformedEnv(
        base,
        Compose(
            InitTracker(),
            DepthHistory(in_key="pixels", out_key="pix_stack", tick_key=tick_key),
            GoalTiling(goal_keys="target", stack_key="pix_stack", out_key="pix_goal_stack"),
        ),
    )


def test_counter_stream_hand_checked() -> None:
    """Every step ticks: at step k the stack is [k-12, k-8, k-4, k], padded with frame 0."""
    env = TransformedEnv(
        CounterPixelEnv(batch=1, with_tick=False),
        DepthHistory(in_key="pixels", out_key="pix_stack", tick_key=None),
    )
    td = env.reset()
    assert pixel_stack_values(td["pix_stack"]).tolist() == [[0, 0, 0, 0]]
    seen = {}
    for k in range(1, 26):
        td = env.rand_step(td)
        seen[k] = pixel_stack_values(td["next", "pix_stack"])[0].tolist()
        td = td["next"]
    assert seen[1] == [0, 0, 0, 1]
    assert seen[4] == [0, 0, 0, 4]
    assert seen[5] == [0, 0, 1, 5]
    assert seen[12] == [0, 4, 8, 12]
    assert seen[13] == [1, 5, 9, 13]
    assert seen[20] == [8, 12, 16, 20]
    for k, v in seen.items():
        assert v == [max(k - o, 0) for o in OFFSETS]


def test_tick_gating_frames_enter_only_on_ticks() -> None:
    env = make_env(batch=5, with_tick=True, period=5)
    ro = env.rollout(64, break_when_any_done=False)
    got = pixel_stack_values(ro["next", "pix_stack"])
    torch.testing.assert_close(got, reference_stacks(ro, with_tick=True), rtol=0, atol=0)
    # world 0 ticks on count 0, 5, 10, ...: at count 60 the stack is [0, 20, 40, 60]
    assert got[0, 59].tolist() == [0, 20, 40, 60]
    # held between ticks: counts 61..64 repeat it
    assert got[0, 63].tolist() == [0, 20, 40, 60]
    # world 1 (ticks at count 4, 9, ...): reset frame 1000 is padding, not ticked again
    assert got[1, 3].tolist() == [1000, 1000, 1000, 1004]


def test_partial_resets_clear_only_their_worlds() -> None:
    env = make_env(batch=6, with_tick=True, p_term=0.04, seed=3)
    env.set_seed(3)
    ro = env.rollout(120, break_when_any_done=False)
    assert ro["is_init"][:, 1:].any(), "the seed must produce partial resets"
    assert not ro["is_init"][:, 1:].all(0).any(), "resets must be partial"
    got = pixel_stack_values(ro["next", "pix_stack"])
    torch.testing.assert_close(got, reference_stacks(ro, with_tick=True), rtol=0, atol=0)
    # root stacks after a reset are [f0]*4 for the reset worlds only
    root = pixel_stack_values(ro["pix_stack"])
    init = ro["is_init"][..., 0]
    first = ro["pixels"][..., 0, 0, 0]
    assert torch.equal(root[init], first[init].unsqueeze(-1).expand(-1, 4))


def test_explicit_partial_reset_keeps_other_worlds() -> None:
    env = make_env(batch=3, with_tick=False)
    td = env.reset()
    for _ in range(9):
        td = env.rand_step(td)["next"]
    before = td["pix_stack"].clone()
    td.set("_reset", torch.tensor([[False], [True], [False]]))
    td = env.reset(td)
    after = pixel_stack_values(td["pix_stack"])
    assert torch.equal(td["pix_stack"][[0, 2]], before[[0, 2]])
    assert after[1].tolist() == [1000.0] * 4
    td = env.rand_step(td)["next"]
    assert pixel_stack_values(td["pix_stack"])[1].tolist() == [1000, 1000, 1000, 1001]
    assert pixel_stack_values(td["pix_stack"])[0].tolist() == [0, 2, 6, 10]


@pytest.mark.parametrize("with_tick", [True, False])
@pytest.mark.parametrize("channel", [True, False])
def test_check_env_specs_and_goal_planes(with_tick: bool, channel: bool) -> None:
    env = make_env(batch=4, with_tick=with_tick, channel=channel, p_term=0.1, seed=1)
    check_env_specs(env)
    spec = env.observation_spec
    assert spec["pix_stack"].shape == (4, 4, 8, 8)
    assert spec["pix_goal_stack"].shape == (4, 4, 2, 8, 8)
    assert isinstance(spec["pix_stack"], Bounded)
    ro = env.rollout(30, break_when_any_done=False)
    assert ro["pix_goal_stack"].shape == (4, 30, 4, 2, 8, 8)
    assert spec["pix_goal_stack"].is_in(ro["pix_goal_stack"][:, 0])
    tiling = env.transform[-1]
    # channel 0 is the depth stack, the goal plane decodes to the target in every frame
    assert torch.equal(ro["pix_goal_stack"][..., 0, :, :], ro["pix_stack"])
    dec = tiling.decode(ro["next", "pix_goal_stack"][..., 1, :, :])  # (4, 30, 4 frames, 2)
    target = ro["next", "target"].unsqueeze(-2).expand_as(dec)
    torch.testing.assert_close(dec, target, rtol=1e-5, atol=1e-4)


def test_same_stacks_as_catframes_without_tick() -> None:
    """Without a tick key, DepthHistory == CatFrames(N=16, dim=-3) frames 3, 7, 11, 15."""
    base = CounterPixelEnv(batch=4, with_tick=False, p_term=0.05, seed=5)
    env = TransformedEnv(
        base,
        Compose(
            CatFrames(N=16, dim=-3, in_keys=["pixels"], out_keys=["cat16"]),
            DepthHistory(in_key="pixels", out_key="pix_stack", tick_key=None),
        ),
    )
    env.set_seed(5)
    ro = env.rollout(80, break_when_any_done=False)
    assert ro["next", "done"].any()
    for prefix in ((), ("next",)):
        cat = ro[prefix + ("cat16",)][..., [3, 7, 11, 15], :, :]
        assert torch.equal(cat, ro[prefix + ("pix_stack",)])


def test_catframes_cannot_skip_non_tick_steps() -> None:
    """The reason DepthHistory exists: CatFrames pushes a frame on every step."""
    base = CounterPixelEnv(batch=1, with_tick=True, period=5)
    env = TransformedEnv(
        base,
        Compose(
            CatFrames(N=16, dim=-3, in_keys=["pixels"], out_keys=["cat16"]),
            DepthHistory(in_key="pixels", out_key="pix_stack", tick_key="cam_tick"),
        ),
    )
    ro = env.rollout(20)
    cat = pixel_stack_values(ro["next", "cat16"][..., [3, 7, 11, 15], :, :])
    ours = pixel_stack_values(ro["next", "pix_stack"])
    assert cat[0, 19].tolist() == [8, 12, 16, 20]  # every step entered
    # entered only on ticks: 0 (reset), 5, 10, 15, 20 -> 12/8/4 entries back are padding
    assert ours[0, 19].tolist() == [0, 0, 0, 20]


def test_offline_forward_rebuilds_online_stacks() -> None:
    """Storing frames only: DepthHistory.forward on the stored [B, T] rebuilds the stacks."""
    env = make_env(batch=5, with_tick=True, p_term=0.05, seed=7)
    env.set_seed(7)
    ro = env.rollout(90, break_when_any_done=False)
    assert ro["next", "done"].any()
    frames_only = ro.exclude("pix_stack", "pix_goal_stack", ("next", "pix_stack"),
                             ("next", "pix_goal_stack"))
    t = DepthHistory(in_key="pixels", out_key="pix_stack", tick_key="cam_tick")
    rebuilt = t(frames_only.clone())
    assert torch.equal(rebuilt["pix_stack"], ro["pix_stack"])
    assert torch.equal(rebuilt["next", "pix_stack"], ro["next", "pix_stack"])
    # with ("next", "done") instead of is_init
    rebuilt = t(frames_only.exclude("is_init", ("next", "is_init")).clone())
    assert torch.equal(rebuilt["pix_stack"], ro["pix_stack"])
    # as a replay-buffer transform: store [T]-long trajectories of frames, stack at sampling
    rb = ReplayBuffer(
        storage=LazyTensorStorage(10),
        transform=DepthHistory(in_key="pixels", out_key="pix_stack", tick_key="cam_tick"),
        batch_size=3,
    )
    rb.extend(frames_only)
    sample, info = rb.sample(return_info=True)
    assert sample["pix_stack"].shape == (3, 90, 4, 8, 8)
    assert torch.equal(sample["pix_stack"], ro["pix_stack"][info["index"]])
    # GoalTiling is stateless: it can run at sampling time too
    tiled = GoalTiling("target", stack_key="pix_stack", out_key="pix_goal_stack")(rebuilt)
    assert torch.equal(tiled["pix_goal_stack"], ro["pix_goal_stack"])


def test_depth_history_default_keys_and_shapes() -> None:
    t = DepthHistory()
    assert (t.in_key, t.out_key, t.tick_key) == ("depth", "depth_stack", "perception_tick")
    assert t.offsets == OFFSETS and t.num_frames == 4
    t2 = DepthHistory(history=9, stride=3)
    assert t2.offsets == (6, 3, 0)
    spec = Composite(depth=Bounded(0.0, 1.0, shape=(2, 1, 6, 5)), shape=(2,))
    out = t.transform_observation_spec(spec.clone())
    assert out["depth_stack"].shape == (2, 4, 6, 5)
    assert isinstance(out["depth_stack"], Bounded)
    spec = Composite(depth=Unbounded(shape=(6, 5), dtype=torch.uint8), shape=())
    out = t.transform_observation_spec(spec.clone())
    assert out["depth_stack"].shape == (4, 6, 5) and out["depth_stack"].dtype == torch.uint8


def test_depth_history_errors() -> None:
    with pytest.raises(ValueError, match="history=16 is not divisible by stride=5"):
        DepthHistory(16, 5)
    with pytest.raises(ValueError, match="stride must be a positive int"):
        DepthHistory(16, 0)
    t = DepthHistory()
    bad = Composite(depth=Unbounded(shape=(2, 3, 6, 5)), shape=(2,))
    with pytest.raises(ValueError, match=r"\(2, 3, 6, 5\)"):
        t.transform_observation_spec(bad)
    with pytest.raises(KeyError, match="depth"):
        t.transform_observation_spec(Composite(pixels=Unbounded(shape=(1, 4, 4)), shape=()))
    td = TensorDict({"depth": torch.zeros(2, 3, 6, 5)}, batch_size=[2])
    with pytest.raises(ValueError, match=r"got \(2, 3, 6, 5\)"):
        t._reset(None, td)
    with pytest.raises(ValueError, match="time dimension"):
        t(TensorDict({"depth": torch.zeros(1, 6, 5)}, batch_size=[]))
