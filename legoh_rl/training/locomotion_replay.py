"""Aggregated DAgger data for the student's locomotion module (extra imitation steps per iteration).

Plain DAgger (Ross et al., 2011) fits the policy to the *aggregate* of every iteration's labelled
states. The unified recipe trains on the latest batch only, because the student's perception
needs whole depth sequences, which are too large to keep (~165 MB per 768-step batch at 64x64).
The locomotion module's inputs are small, though: ``z_uni`` (32), ``proprio`` (D), ``delta_g0``
and ``goal_next`` (2 each), as the student held them while acting. :class:`LocomotionReplay`
keeps them, with the teacher's action, for the last ``capacity`` steps, and runs ``steps``
extra minibatch updates of the locomotion MLP alone on random samples of that window, with the
action term of :class:`~legoh_rl.objectives.DAggerLoss`.

The stored perception outputs were computed by an older perception module; with a window of a
few dozen iterations they change little, and the perception keeps its own gradient from the
main update. The window is part of a run's checkpoint (:meth:`LocomotionReplay.state_dict`), so a
resumed run samples the same data as one that never stopped.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

from legoh_rl.objectives import DAggerLoss

__all__ = ["LocomotionReplay"]


class LocomotionReplay:
    """A FIFO window of locomotion inputs and teacher actions, and imitation steps on it.

    Args:
        actor: the student's locomotion ``ProbabilisticActor``; its first module (the network
            writing ``loc``) is trained, reading ``actor.module[0].in_keys``.
        capacity: steps kept (the oldest are overwritten), >= 1.
        batch_size: samples per extra update, >= 1.
        steps: extra updates per :meth:`train` call, >= 1.
        action_key: where the teacher's action is stored (``"action_tea"``, written by
            :meth:`~legoh_rl.training.distill.Teacher.label`).
        seed: seeds the sampling.
        device: where the window is kept and sampled (the network's device).

    Raises:
        ValueError: a size below 1 (names it).
    """

    def __init__(self, actor, capacity: int, batch_size: int, steps: int, action_key: str = "action_tea",
                 seed: int = 0, device: torch.device | str = "cpu") -> None:
        for name, value in (("capacity", capacity), ("batch_size", batch_size), ("steps", steps)):
            if int(value) < 1:
                raise ValueError(f"LocomotionReplay {name} must be >= 1, got {value!r}")
        self.net = actor.module[0]
        self.keys = [*self.net.in_keys, action_key]
        self.steps = int(steps)
        self.capacity = int(capacity)
        self.loss = DAggerLoss(w1=0.0, w2=0.0, w3=1.0)
        self.loss.set_keys(action_tea=action_key, action_uni="loc")
        self._gen = torch.Generator().manual_seed(int(seed))
        self.device = torch.device(device)
        self.buffer = ReplayBuffer(storage=LazyTensorStorage(int(capacity), device=self.device),
                                   sampler=RandomSampler(),
                                   batch_size=int(batch_size))

    def __len__(self) -> int:
        return len(self.buffer)

    def state_dict(self) -> dict:
        """The window's contents, write cursor and sampling stream (for a run's checkpoint)."""
        return {"capacity": self.capacity, "buffer": self.buffer.state_dict(), "generator": self._gen.get_state()}

    def load_state_dict(self, state: dict, stream: bool = True) -> None:
        """Restore what :meth:`state_dict` saved (``stream=False``: the contents and cursor, while
        sampling keeps this window's own seeded stream).

        Raises:
            ValueError: the saved window has another capacity than this one (names both).
        """
        if int(state["capacity"]) != self.capacity:
            raise ValueError(f"LocomotionReplay: the saved window holds {state['capacity']} steps, this one "
                             f"{self.capacity} (dagger_replay.capacity must be the one the run was trained with)")
        self.buffer.load_state_dict(state["buffer"])
        if stream:
            self._gen.set_state(state["generator"])

    def extend(self, data: TensorDictBase) -> None:
        """Add every step of a collected batch (any batch shape; it is flattened).

        Raises:
            KeyError: ``data`` lacks one of the locomotion inputs or the teacher's action (names it).
        """
        missing = [k for k in self.keys if k not in data.keys()]
        if missing:
            raise KeyError(f"LocomotionReplay needs {missing} in the batch (keys: {sorted(data.keys())})")
        self.buffer.extend(data.select(*self.keys).reshape(-1).detach().clone())

    def train(self, optim: torch.optim.Optimizer, max_grad_norm: float | None = None) -> float:
        """Run ``steps`` updates of the locomotion network on random samples of the window.

        Args:
            optim: an optimiser that holds the network's parameters (other parameters get no
                gradient and are left as they are).
            max_grad_norm: clip the network's gradient norm to this (None: no clipping).

        Returns:
            The mean unweighted action loss (SmoothL1, averaged over joints) over the updates;
            NaN when the buffer is empty (nothing is trained).
        """
        if len(self.buffer) == 0:
            return float("nan")
        params = list(self.net.parameters())
        total = 0.0
        # this call's draws from a generator of their own, seeded from the window's stream: the
        # numbers torch's global generator gave under that seed, which it neither reads nor moves
        # (collector.overlap collects from it in another thread meanwhile)
        draws = torch.Generator(device=self.device)
        draws.manual_seed(int(torch.randint(0, 2**31 - 1, (1,), generator=self._gen)))
        self.buffer.set_rng(draws)
        try:
            batches = [self.buffer.sample() for _ in range(self.steps)]
        finally:
            self.buffer.set_rng(None)  # the buffer's state_dict keeps no generator
        for batch in batches:
            out = self.net(batch.select(*self.net.in_keys))
            batch.set("loc", out["loc"])
            loss = self.loss(batch)["loss_im_action"]
            optim.zero_grad()
            loss.backward()
            if max_grad_norm is not None:
                torch.nn.utils.clip_grad_norm_(params, max_grad_norm)
            optim.step()
            total += float(loss.detach())
        return total / self.steps
