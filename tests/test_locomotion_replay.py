"""LocomotionReplay: aggregated DAgger data for the student's locomotion MLP."""

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict

from legoh_rl.modules.configs import LocomotionConfig
from legoh_rl.modules.locomotion import make_locomotion_actor
from legoh_rl.training.locomotion_replay import LocomotionReplay

D, A = 5, 3


def actor():
    torch.manual_seed(0)
    return make_locomotion_actor(LocomotionConfig(proprio_dim=D, num_actions=A, latent_dim=4, layers=(16,)))


def batch(n, t, target=0.3, seed=0):
    g = torch.Generator().manual_seed(seed)
    return TensorDict({"z_uni": torch.rand(n, t, 4, generator=g), "proprio": torch.rand(n, t, D, generator=g),
                       "delta_g0": torch.rand(n, t, 2, generator=g), "goal_next": torch.rand(n, t, 2, generator=g),
                       "action_tea": torch.full((n, t, A), target), "depth": torch.zeros(n, t, 8, 8)}, [n, t])


def test_sizes_are_checked_by_name():
    with pytest.raises(ValueError, match="capacity must be >= 1, got 0"):
        LocomotionReplay(actor(), 0, 8, 1)
    with pytest.raises(ValueError, match="steps must be >= 1, got -1"):
        LocomotionReplay(actor(), 8, 8, -1)


def test_the_window_keeps_the_last_capacity_steps_of_the_locomotion_inputs():
    rp = LocomotionReplay(actor(), capacity=50, batch_size=8, steps=1)
    rp.extend(batch(4, 10))
    assert len(rp) == 40
    stored = rp.buffer.storage[:40]
    assert set(stored.keys()) == {"z_uni", "proprio", "delta_g0", "goal_next", "action_tea"}  # no depth
    rp.extend(batch(4, 10, target=0.7))
    assert len(rp) == 50  # FIFO: 30 of the first batch were overwritten
    targets = rp.buffer.storage[:50]["action_tea"][:, 0]
    assert (targets == 0.7).sum() == 40 and (targets == 0.3).sum() == 10
    with pytest.raises(KeyError, match=r"needs \['action_tea'\]"):
        rp.extend(batch(1, 2).exclude("action_tea"))


def test_an_empty_window_trains_nothing():
    a = actor()
    rp = LocomotionReplay(a, 8, 8, 3)
    before = [p.clone() for p in a.parameters()]
    assert torch.isnan(torch.tensor(rp.train(torch.optim.SGD(a.parameters(), lr=0.1))))
    assert all(torch.equal(p, q) for p, q in zip(before, a.parameters(), strict=True))


def test_the_loss_is_smooth_l1_to_the_teachers_action():
    """One step at lr 0 on a window of identical samples returns SmoothL1(loc, a_tea) by hand."""
    a = actor()
    rp = LocomotionReplay(a, 16, 4, 1)
    one = batch(1, 1, target=0.3)
    rp.extend(one.expand(1, 16).clone())
    loc = a.module[0](one[0, 0].clone())["loc"].detach()
    expected = F.smooth_l1_loss(loc, torch.full((A,), 0.3)).item()
    d = (loc - 0.3).abs()
    assert expected == pytest.approx(torch.where(d < 1, 0.5 * d**2, d - 0.5).mean().item())
    assert rp.train(torch.optim.SGD(a.parameters(), lr=0.0)) == pytest.approx(expected, rel=1e-5)


def test_training_on_the_window_fits_the_teacher_and_touches_only_the_network():
    a = actor()
    other = torch.nn.Parameter(torch.ones(3))  # e.g. the perception's weights, in the same optimiser
    optim = torch.optim.Adam([*a.parameters(), other], lr=1e-2)
    rp = LocomotionReplay(a, 200, 32, 100, seed=1)
    rp.extend(batch(8, 20, target=0.3))
    first = rp.train(torch.optim.SGD(a.parameters(), lr=0.0))
    last = rp.train(optim, max_grad_norm=1.0)
    again = rp.train(optim, max_grad_norm=1.0)
    assert again < last < first and again < 0.1 * first
    assert torch.equal(other, torch.ones(3))
    loc = a.module[0](batch(2, 3, seed=5).select("z_uni", "proprio", "delta_g0", "goal_next"))["loc"]
    assert torch.allclose(loc, torch.full_like(loc, 0.3), atol=0.05)


def test_state_dict_round_trip_continues_the_same_window_and_samples():
    a = actor()
    rp = LocomotionReplay(a, 20, 4, 2, seed=3)
    rp.extend(batch(3, 9))  # 27 steps through a 20-step window: the cursor has wrapped
    copy = LocomotionReplay(actor(), 20, 4, 2, seed=99)
    copy.load_state_dict(rp.state_dict())
    assert len(copy) == 20 and (copy.buffer.storage[:20] == rp.buffer.storage[:20]).all()
    nxt = batch(1, 5, target=0.9, seed=7)
    rp.extend(nxt)
    copy.extend(nxt)  # the same slots are overwritten
    assert (copy.buffer.storage[:20] == rp.buffer.storage[:20]).all()
    b = actor()  # same initial weights: the same samples give the same losses
    assert copy.train(torch.optim.SGD(b.parameters(), lr=0.0)) == rp.train(torch.optim.SGD(a.parameters(), lr=0.0))
    with pytest.raises(ValueError, match="saved window holds 20 steps, this one 10"):
        LocomotionReplay(actor(), 10, 4, 2).load_state_dict(rp.state_dict())


def test_sampling_draws_from_its_own_stream_and_leaves_the_global_generator_alone():
    """Each train() samples with the numbers torch's generator gives under a seed drawn from the
    window's stream, without reading or moving the global generator (a collecting thread's)."""
    rp = LocomotionReplay(actor(), 20, 4, 3, seed=3)
    rp.extend(batch(2, 10))
    seed = int(torch.randint(0, 2**31 - 1, (1,), generator=torch.Generator().manual_seed(3)))
    expected = torch.randint(20, (3, 4), generator=torch.Generator().manual_seed(seed))  # 3 steps of 4 indices
    seen = []
    real = rp.buffer.storage.get

    def get(index):
        seen.append(torch.as_tensor(index).clone())
        return real(index)

    rp.buffer.storage.get = get
    torch.manual_seed(11)
    before = torch.get_rng_state()
    rp.train(torch.optim.SGD(rp.net.parameters(), lr=0.0))
    assert torch.equal(torch.get_rng_state(), before)
    assert torch.equal(torch.stack(seen), expected)
    assert rp.buffer.storage._rng is None  # nothing of it in the buffer's state
