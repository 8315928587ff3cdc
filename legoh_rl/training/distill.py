"""Distillation pieces of the unified recipe: the frozen teacher and the student's training pass.

Keys follow docs/keys.md. The teacher fills ``z_tea``, ``goals_tea`` and ``action_tea`` (its
deterministic action, ``loc``) on the same steps the student acted on; the student's pass
recomputes its perception on those steps (with gradients, holding outputs between perception
ticks exactly as while acting) and writes its deterministic action under ``loc_uni`` so the
rollout's ``loc``/``scale`` (needed for PPO's KL) stay untouched.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from legoh_rl.modules.oracle import make_oracle_actor, make_oracle_critic, make_oracle_networks
from legoh_rl.training.builders import oracle_networks
from legoh_rl.training.checkpoint import load_checkpoint

__all__ = ["Teacher", "DAggerMixture", "dagger_beta", "student_pass", "STUDENT_ACTION_KEY"]

STUDENT_ACTION_KEY = "loc_uni"


class Teacher:
    """A frozen oracle loaded from an ``oracle_ppo.py`` checkpoint.

    Args:
        path: the oracle checkpoint (loaded to the CPU, then moved to ``device``).
        robot: the student's robot (a mismatch is refused).
        device: where the networks run (the recipe's device).

    Attributes:
        networks: the oracle's networks (no gradients), on ``device``; ``actor`` its ProbabilisticActor.
    """

    def __init__(self, path: str, robot: str, device: torch.device | str = "cpu") -> None:
        state = load_checkpoint(path)
        meta = state.get("meta", {})
        if meta.get("kind") != "oracle":
            raise ValueError(f"{path}: the teacher must be an oracle checkpoint, got kind {meta.get('kind')!r}")
        if meta.get("robot") != robot:
            raise ValueError(f"{path}: robot: checkpoint has {meta.get('robot')!r}, this run needs {robot!r}")
        self.meta = meta
        self.device = torch.device(device)
        self.networks = oracle_networks(state).to(self.device)
        self.networks.requires_grad_(False)
        self.networks.eval()
        self.actor = make_oracle_actor(self.networks)
        self._net = self.actor.module[0]  # encoders + actor MLP, writes z_tea, loc, scale
        #: observation keys the teacher reads
        self.in_keys = list(self._net.in_keys)
        head = self.networks.actor.head
        #: the teacher's exploration std, (A,) (its learned std under its ceiling)
        self.action_std = head.log_std.exp().clamp(head.min_std, head.max_std).detach().clone()

    @torch.no_grad()
    def label(self, td: TensorDictBase) -> TensorDictBase:
        """Write ``z_tea`` (*B, 32), ``priv_latent_tea`` (*B, 20), ``goals_tea`` (*B, N, 2) and
        ``action_tea`` (*B, A) for every step of ``td`` (any batch ``*B``)."""
        out = self._net(td.select(*self._net.in_keys).copy())
        td.set("z_tea", out["z_tea"])
        td.set("priv_latent_tea", out["priv_latent"])
        td.set("action_tea", out["loc"])
        td.set("goals_tea", td.get("expert_goals"))
        return td

    def make_critic(self):
        """A critic with the oracle's architecture and trained weights (asymmetric: it reads the
        privileged observations, which exist only in simulation, as in the oracle stage)."""
        networks = make_oracle_networks(self.networks.cfg).to(self.device)
        networks.load_state_dict(self.networks.state_dict())
        networks.requires_grad_(True)
        return make_oracle_critic(networks), networks


def dagger_beta(iteration: int, beta0: float, dagger_iters: int) -> float:
    """DAgger's mixing weight at an iteration: ``beta0`` decayed linearly to 0 at ``dagger_iters``.

    ``beta`` is the probability that the teacher's action is executed at a step (Ross et al.,
    2011: ``pi_i = beta_i pi* + (1 - beta_i) pi_hat_i``). It is 0 from ``dagger_iters`` on, when
    PPO joins and the rollout must come from the student's own distribution.
    """
    if not 0.0 <= beta0 <= 1.0:
        raise ValueError(f"beta0 must be in [0, 1], got {beta0}")
    if iteration >= dagger_iters or dagger_iters <= 0:
        return 0.0
    return beta0 * (1.0 - iteration / dagger_iters)


class DAggerMixture(TensorDictModuleBase):
    """The collection policy of DAgger: the student acts, but at each step and world the
    teacher's deterministic action replaces the student's with probability :attr:`beta`.

    The student still runs on every step (its recurrent perception state advances as if it had
    acted), so switching ``beta`` to 0 leaves exactly the student's policy. With
    :attr:`student_mean` the student's executed action is its mean (``loc``) rather than a sample:
    imitation needs no exploration noise, and noise makes the robots fall into states the
    deterministic student would never visit. Set it False when PPO joins.

    Args:
        student_policy: the student's acting module (writes ``action``).
        teacher: the frozen :class:`Teacher` (reads the privileged observations of the step).
        seed: seeds the per-step coin flips.

    Writes ``action`` (*B, A) and ``teacher_acted`` (*B,) bool.
    """

    def __init__(self, student_policy: TensorDictModuleBase, teacher: Teacher, seed: int = 0) -> None:
        super().__init__()
        self.student_policy = student_policy
        self.teacher = teacher
        self.beta = 1.0
        self.student_mean = False
        self.in_keys = list(dict.fromkeys([*student_policy.in_keys, *teacher.in_keys]))
        self.out_keys = list(dict.fromkeys([*student_policy.out_keys, "action", "teacher_acted"]))
        self._gen = torch.Generator().manual_seed(int(seed))

    def __getstate__(self) -> dict:
        # the coin-flip generator's state as bytes: pickled as a tensor, a temporary one, it would
        # reach a spawned collector worker as a shared-memory file freed before the worker reads it
        state = self.__dict__.copy()
        state["_gen"] = bytes(self._gen.get_state().numpy())
        return state

    def __setstate__(self, state: dict) -> None:
        gen = torch.Generator()
        gen.set_state(torch.frombuffer(bytearray(state["_gen"]), dtype=torch.uint8))
        super().__setstate__({**state, "_gen": gen})

    def set_schedule(self, beta: float, student_mean: bool) -> None:
        """Set :attr:`beta` and :attr:`student_mean` (one call: how the training loop sets them in
        collector worker processes)."""
        self.beta, self.student_mean = float(beta), bool(student_mean)

    def reseed(self, seed: int) -> None:
        """Restart the coin flips from ``seed`` (each collector worker its own stream)."""
        self._gen.manual_seed(int(seed))

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        td = self.student_policy(td)
        if self.student_mean:
            td.set("action", td.get("loc").clone())
        acted = torch.zeros(td.batch_size, dtype=torch.bool, device=td.device)
        if self.beta > 0.0:
            acted = torch.rand(td.batch_size, generator=self._gen).to(td.device) < self.beta
            teacher_action = self.teacher.label(td.select(*self.teacher.in_keys).copy())["action_tea"]
            action = td.get("action")
            td.set("action", torch.where(acted[..., None], teacher_action.to(action.dtype), action))
        td.set("teacher_acted", acted)
        return td


def student_pass(student, td: TensorDictBase, encoder_grad_fraction: float = 1.0,
                 generator: torch.Generator | None = None) -> TensorDictBase:
    """Recompute the student's perception (with gradients) and deterministic action on ``td``.

    ``td`` is ``[..., T]`` (time last). Writes ``z_uni``, ``delta_g0``, ``goals_uni``,
    ``goal_next`` (via :meth:`PerceptionHold.hold_forward`) and ``loc_uni`` (A,).
    ``encoder_grad_fraction`` < 1: the perception encoder runs on that fraction of the tick steps,
    the features recorded while acting on the others (a student made with ``record_features``),
    drawn from ``generator`` (``None``: torch's global generator).
    """
    student.hold.hold_forward(td, encoder_grad_fraction=encoder_grad_fraction, generator=generator)
    net = student.actor.module[0]
    out = net(td.select(*net.in_keys))
    td.set(STUDENT_ACTION_KEY, out["loc"])
    return td
