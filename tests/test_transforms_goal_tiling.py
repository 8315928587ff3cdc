"""GoalTiling: plane layout, exact invertibility, shapes, specs and errors (no env needed)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, Unbounded

from legoh_rl.transforms import GoalTiling


def goals() -> torch.Tensor:
    g = torch.randn(200, 2, generator=torch.Generator().manual_seed(0)) * 30.0
    special = torch.tensor(
        [[0.0, 0.0], [1e-6, 0.0], [0.0, -3.0], [-5.0, 0.0], [800.0, -600.0], [0.3, 0.4]]
    )
    return torch.cat([g, special])


@pytest.mark.parametrize("encoding", ["polar", "cartesian"])
@pytest.mark.parametrize("hw", [(8, 8), (64, 64), (5, 7)])
def test_decode_inverts_encode(encoding: str, hw: tuple[int, int]) -> None:
    t = GoalTiling(encoding=encoding, scale=10.0)
    g = goals()
    planes = t.encode(g, *hw)
    assert planes.shape == (g.shape[0], *hw)
    assert planes.abs().max() <= 1.0
    torch.testing.assert_close(t.decode(planes), g, rtol=2e-5, atol=2e-5)


def test_polar_layout_by_hand() -> None:
    """W = 6, three bands of two columns: cos, sin, d / (d + scale)."""
    t = GoalTiling(scale=5.0)
    plane = t.encode(torch.tensor([3.0, 4.0]), 2, 6)  # d = 5, heading (0.6, 0.8)
    row = torch.tensor([0.6, 0.6, 0.8, 0.8, 0.5, 0.5])
    torch.testing.assert_close(plane, row.expand(2, 6))
    zero = t.encode(torch.zeros(2), 1, 6)
    assert zero.tolist() == [[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]]
    assert t.decode(zero).tolist() == [0.0, 0.0]


def test_cartesian_layout_by_hand() -> None:
    """W = 4, two bands: softsign(dx / scale), softsign(dy / scale)."""
    t = GoalTiling(encoding="cartesian", scale=2.0)
    plane = t.encode(torch.tensor([2.0, -6.0]), 1, 4)
    assert plane.tolist() == [[0.5, 0.5, -0.75, -0.75]]


def test_transform_shapes_two_goal_keys_and_dtype() -> None:
    t = GoalTiling(["goal_gps", "waypoint_gps"])
    assert t.num_planes == 2
    td = TensorDict(
        {
            "depth_stack": torch.randint(0, 255, (3, 5, 4, 16, 16), dtype=torch.uint8),
            "goal_gps": torch.randn(3, 5, 2) * 10,
            "waypoint_gps": torch.randn(3, 5, 2),
        },
        batch_size=[3, 5],  # e.g. a replay-buffer sample [N, T]
    )
    out = t(td)["depth_goal_stack"]
    assert out.shape == (3, 5, 4, 3, 16, 16) and out.dtype == torch.float32
    assert torch.equal(out[..., 0, :, :], td["depth_stack"].float())
    for frame in range(4):
        dec = t.decode(out[:, :, frame, 1:])  # (3, 5, 2 planes, 2)
        torch.testing.assert_close(dec[..., 0, :], td["goal_gps"], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(dec[..., 1, :], td["waypoint_gps"], rtol=1e-5, atol=1e-5)


def test_output_spec() -> None:
    t = GoalTiling()
    spec = Composite(
        depth_stack=Bounded(0.0, 1.0, shape=(2, 4, 8, 8)),
        goal_gps=Unbounded(shape=(2, 2)),
        shape=(2,),
    )
    out = t.transform_observation_spec(spec)["depth_goal_stack"]
    assert isinstance(out, Bounded) and out.shape == (2, 4, 2, 8, 8)
    assert out.space.low[:, :, 0].min() == 0 and out.space.low[:, :, 1].min() == -1
    assert out.space.high[:, :, 1].max() == 1
    spec = Composite(
        depth_stack=Unbounded(shape=(4, 8, 8)), goal_gps=Unbounded(shape=(2,)), shape=()
    )
    assert GoalTiling().transform_observation_spec(spec)["depth_goal_stack"].shape == (4, 2, 8, 8)


def test_errors_name_bad_values() -> None:
    with pytest.raises(ValueError, match="encoding must be one of"):
        GoalTiling(encoding="log")
    with pytest.raises(ValueError, match="goal_dim=3"):
        GoalTiling(goal_dim=3)
    with pytest.raises(ValueError, match="scale must be a finite positive number, got -1.0"):
        GoalTiling(scale=-1)
    t = GoalTiling()
    with pytest.raises(ValueError, match="width 2 is smaller than the 3 bands"):
        t.encode(torch.zeros(2), 4, 2)
    td = TensorDict({"depth_stack": torch.zeros(4, 8, 8), "goal_gps": torch.zeros(3)}, [])
    with pytest.raises(ValueError, match=r"goal 'goal_gps' must have shape \(\*batch, 2\)"):
        t(td)
    with pytest.raises(KeyError, match="add DepthHistory before"):
        t(TensorDict({"goal_gps": torch.zeros(2)}, []))
    spec = Composite(depth_stack=Unbounded(shape=(4, 8, 8)), shape=())
    with pytest.raises(KeyError, match="goal_gps"):
        t.transform_observation_spec(spec)
    # cartesian supports any dimension
    t3 = GoalTiling(encoding="cartesian", goal_dim=3)
    g = torch.tensor([[1.0, -2.0, 50.0]])
    torch.testing.assert_close(t3.decode(t3.encode(g, 4, 9)), g, rtol=1e-5, atol=1e-5)
