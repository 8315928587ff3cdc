"""The oracle's PPO update (``recipes/oracle_ppo.py``, issue 52's speed-ups) on a tiny env: the
speed-ups that keep the numerics are held to the bit against the plain loop they replaced; the
switches that change them (``fused_adam``) to what they claim."""

import copy
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs.utils import ExplorationType, set_exploration_type

from legoh_rl.objectives.ppo import gaussian_kl, policy_kl
from legoh_rl.training.checkpoint import load_checkpoint

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=2", "ppo.num_minibatches=2", "logger.backend=csv"]


def cfg_of(overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name="oracle_ppo", overrides=overrides)


@pytest.fixture(scope="module")
def trainer(tmp_path_factory):
    """A built oracle trainer (tiny env) and one collected ``[4, 8]`` batch of it."""
    t = oracle_ppo.build(cfg_of(TINY + [f"checkpoint.dir={tmp_path_factory.mktemp('ck')}"]))
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        batch = t.env.rollout(8, t.actor, break_when_any_done=False)
    return t, batch


def plain_step(mb, loss, optim, cfg) -> None:
    """One clipped-PPO step on minibatch ``mb``, as the recipe takes it (gradient clipped)."""
    out = loss(mb)
    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
    optim.zero_grad()
    total.backward()
    torch.nn.utils.clip_grad_norm_(loss.parameters(), cfg.ppo.max_grad_norm)
    optim.step()


def reference_update(data, loss, gae, optim, sched, actor, cfg) -> None:
    """The update as it was before issue 52: minibatches indexed out of the whole batch (next
    observations, reward terms and all), the KL from a full actor call (sampling under the
    default interaction type, log-probability) after each step."""
    with torch.no_grad():
        gae(data)
    flat = data.reshape(-1)
    for _ in range(cfg.ppo.num_epochs):
        for idx in torch.randperm(flat.shape[0]).chunk(cfg.ppo.num_minibatches):
            mb = flat[idx]
            plain_step(mb, loss, optim, cfg)
            with torch.no_grad():
                new = actor(mb.select(*actor.in_keys))
            sched.step(gaussian_kl(mb["loc"], mb["scale"], new["loc"], new["scale"]).mean())


def trained_state(t, batch, update, cfg) -> tuple[dict, dict, float]:
    """``(loss state, optimiser state, learning rate)`` after ``update`` on ``batch`` from ``t``'s
    current state (which is put back afterwards), torch's RNG seeded as the recipe leaves it."""
    saved = copy.deepcopy((t.loss.state_dict(), t.optim.state_dict(), t.sched.state_dict()))
    torch.manual_seed(0)
    update(batch.clone(), t.loss, t.gae, t.optim, t.sched, t.actor, cfg)
    state = copy.deepcopy((t.loss.state_dict(), t.optim.state_dict(), t.sched.lr))
    t.loss.load_state_dict(saved[0])
    t.optim.load_state_dict(saved[1])
    t.sched.load_state_dict(saved[2])
    return state


def assert_same(a: tuple, b: tuple) -> None:
    """Loss parameters and buffers, Adam's moments and the learning rate equal to the bit."""
    (loss_a, optim_a, lr_a), (loss_b, optim_b, lr_b) = a, b
    assert loss_a.keys() == loss_b.keys()
    for k in loss_a:
        assert torch.equal(loss_a[k], loss_b[k]), k
    for i, s in optim_a["state"].items():
        for k, v in s.items():
            assert torch.equal(v, optim_b["state"][i][k]), (i, k)
    assert lr_a == lr_b


def test_ppo_update_matches_the_whole_batch_loop(trainer):
    t, batch = trainer
    assert {("next", "proprio"), "goal_gps", "z_tea"} <= set(batch.keys(True))  # some of what is left out
    stepped = trained_state(t, batch, oracle_ppo.ppo_update, t.cfg)
    assert_same(stepped, trained_state(t, batch, reference_update, t.cfg))
    assert not all(torch.equal(v, t.loss.state_dict()[k]) for k, v in stepped[0].items())  # it did train


def rsl_rl_order_update(data, loss, gae, optim, sched, actor, cfg) -> None:
    """rsl_rl's order, by hand: before each step but the batch's first, the KL of the parameters
    about to step (a separate actor pass) sets that step's learning rate."""
    with torch.no_grad():
        gae(data)
    flat = data.reshape(-1)
    first = True
    for _ in range(cfg.ppo.num_epochs):
        for idx in torch.randperm(flat.shape[0]).chunk(cfg.ppo.num_minibatches):
            mb = flat[idx]
            if not first:
                sched.step(policy_kl(actor, mb))
            first = False
            plain_step(mb, loss, optim, cfg)


def test_kl_measure_loss_forward_is_rsl_rls_order_without_the_actor_pass(trainer, monkeypatch):
    t, batch = trainer
    cfg = cfg_of(TINY + ["kl_measure=loss_forward", "checkpoint.dir=unused"])
    measured, kls = [], []
    real_kl, real_step = oracle_ppo.policy_kl, t.sched.step
    monkeypatch.setattr(oracle_ppo, "policy_kl", lambda *a, **k: measured.append(1) or real_kl(*a, **k))
    monkeypatch.setattr(t.sched, "step", lambda kl: kls.append(float(kl)) or real_step(kl))
    stepped = trained_state(t, batch, oracle_ppo.ppo_update, cfg)
    assert not measured  # the KL came from the loss's own forward pass ...
    assert len(kls) == 2 * 2 - 1 and all(k > 0 for k in kls)  # ... before every step but the batch's first
    assert_same(stepped, trained_state(t, batch, rsl_rl_order_update, cfg))


def test_kl_measure_must_be_a_known_one(tmp_path):
    with pytest.raises(ValueError, match=r"unknown kl_measure 'before'; valid: \['after_step', 'loss_forward'\]"):
        oracle_ppo.train(cfg_of(TINY + ["kl_measure=before", f"checkpoint.dir={tmp_path}"]))


def test_fused_adam_changes_the_rounding_only(tmp_path):
    """``fused_adam`` (a switch, off by default): two iterations from the same seed end within
    float rounding of the per-tensor Adam's parameters, not on them."""
    states = {}
    for fused in (False, True):
        ck = tmp_path / f"fused{fused}"
        oracle_ppo.train(cfg_of(TINY + ["collector.total_frames=64", f"checkpoint.dir={ck}", f"fused_adam={fused}"]))
        saved = load_checkpoint(ck / "last.pt")
        assert saved["iteration"] == 2 and saved["optim"]["param_groups"][0]["fused"] is (True if fused else None)
        states[fused] = saved["loss"]
    for k, v in states[False].items():
        torch.testing.assert_close(states[True][k], v, rtol=0, atol=1e-5, msg=k)


def test_a_resumed_run_takes_its_own_fused_adam(tmp_path):
    """torch's loader would take the checkpoint's ``fused``; the recipe keeps the run's setting
    (and the checkpoint's moments)."""
    for first, then in ((False, True), (True, False)):
        ck = tmp_path / f"from{first}"
        oracle_ppo.train(cfg_of(TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}", f"fused_adam={first}"]))
        saved = load_checkpoint(ck / "last.pt")["optim"]
        parts = oracle_ppo.build(cfg_of(TINY + ["collector.total_frames=64", f"checkpoint.dir={ck}",
                                                "checkpoint.resume=auto", f"fused_adam={then}"]))
        assert all(bool(g["fused"]) is then for g in parts.optim.param_groups)
        for i, s in parts.optim.state_dict()["state"].items():
            assert all(torch.equal(v, saved["state"][i][k]) for k, v in s.items()), i
