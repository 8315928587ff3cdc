"""Collection over K worker processes: each steps a slice of the run's worlds (``collector.workers``).

With ``collector.workers=K > 1`` the training loop collects with torchrl's
:class:`~torchrl.collectors.MultiSyncCollector`: worker ``k`` builds its own
:class:`~legoh_rl.envs.HikingEnv` of ``N / K`` worlds (:class:`EnvSlice`, a picklable factory:
workers are spawned processes) with

* its own seed, ``env.seed + k`` (spawns, randomisation, noise), on the trail grid of
  ``env.seed`` (every worker hikes the terrain a single-process run would);
* its own physics threads, ``env.num_threads / K`` (at least 1; ``null``: the usable CPUs / K);
* the recipe's env wrapping (the student's transforms), then ``RewardSum`` and ``StepCounter``.

Each batch concatenates the slices along the worlds: ``[N, T]`` with worlds ``k N/K .. (k+1) N/K - 1``
from worker ``k``, the same frames per iteration as one process collecting ``N`` worlds.

The main process keeps its own ``HikingEnv`` of ``N`` worlds (the trainer's ``env``: specs,
networks, logs, checkpoints) that is not stepped: :class:`WorkerEnvs` mirrors the workers' env
state into it after every batch (curriculum levels and categories concatenated, counters summed)
and keeps each worker's exact state (:attr:`HikingEnv.slice_states`), which the checkpoint holds
under ``env["workers"]``. Resuming with the same K hands each worker its own state back (curriculum
levels, random stream, counters) and resets the worlds, as a one-process resume does; resuming
with another K than the checkpoint's is refused (the random streams of K workers cannot be split or
merged), unless ``collector.allow_new_workers=true`` (levels and counters carried, each worker's
random stream afresh from ``env.seed + k``). docs/scaling.md has the details and the speed-ups.
"""

from __future__ import annotations

import dataclasses
import os
import signal
from collections.abc import Callable

import numpy as np
import torch
from torchrl.collectors import MultiSyncCollector
from torchrl.envs import Compose, EnvBase, RewardSum, StepCounter, TransformedEnv

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.physics import default_num_threads

__all__ = ["slice_config", "EnvSlice", "WorkerEnvs", "make_worker_collector", "check_workers"]

#: where a worker's collector finds its HikingEnv (TransformedEnv unwraps nested transforms)
BASE_ENV = "env.base_env"
#: ... and its :class:`WorkerProcess`
PROCESS = f"{BASE_ENV}.worker_process"


class WorkerProcess:
    """What a worker's state holds beyond its env's: the process's torch generator, which samples
    the policy's actions there (a one-process run keeps it in the checkpoint's ``rng``). Reached
    from the main process as ``env.base_env.worker_process`` of the worker's collector."""

    @staticmethod
    def rng_state() -> bytes:
        """The generator's state, as bytes (a tensor would cross the pipe as shared memory)."""
        return bytes(torch.get_rng_state().numpy())

    @staticmethod
    def set_rng_state(state: bytes) -> None:
        torch.set_rng_state(torch.frombuffer(bytearray(state), dtype=torch.uint8))


def check_workers(workers, num_envs: int) -> int:
    """``collector.workers`` as an int that divides ``env.num_envs``.

    Raises:
        ValueError: not a positive integer, or not a divisor of ``num_envs`` (names both).
    """
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ValueError(f"collector.workers must be a positive integer, got {workers!r}")
    if num_envs % workers:
        raise ValueError(f"collector.workers={workers} must divide env.num_envs={num_envs}: each worker steps "
                         "env.num_envs / collector.workers worlds")
    return workers


def slice_config(cfg: HikingEnvConfig, index: int, workers: int) -> HikingEnvConfig:
    """The env config of worker ``index`` of ``workers``: ``num_envs / workers`` worlds, seed
    ``seed + index``, ``num_threads / workers`` physics threads (at least 1; ``None`` counts the
    usable CPUs)."""
    threads = cfg.num_threads if cfg.num_threads is not None else default_num_threads()
    return dataclasses.replace(cfg, num_envs=cfg.num_envs // workers, seed=cfg.seed + index,
                               num_threads=max(1, int(threads) // workers))


class EnvSlice:
    """Picklable factory of worker ``index``'s env (what a spawned worker process calls).

    Args:
        cfg: the run's env config (all ``N`` worlds; :func:`slice_config` takes the slice).
        index, workers: which slice of how many.
        wrap: ``wrap(env) -> EnvBase``, the recipe's transforms around the slice's HikingEnv
            (``None``: none; a module-level function or ``functools.partial``, to be picklable).

    Returns (when called): ``TransformedEnv(wrap(HikingEnv(slice)), RewardSum + StepCounter)``,
    batch ``[N / workers]``, on ``cfg.device``. Called in the worker process, it also seeds that
    process's torch generator (the policy's action samples) with ``seed + index``.
    """

    def __init__(self, cfg: HikingEnvConfig, index: int, workers: int,
                 wrap: Callable[[HikingEnv], EnvBase] | None = None) -> None:
        self.cfg, self.index, self.workers, self.wrap = cfg, int(index), int(workers), wrap

    def __call__(self) -> EnvBase:
        from legoh_rl.envs.trail_source import trails_for

        trails = trails_for(self.cfg.categories, self.cfg.variants, self.cfg.seed,  # the run's terrain
                            pit_depths=self.cfg.pit_depths)
        cfg = slice_config(self.cfg, self.index, self.workers)
        torch.manual_seed(cfg.seed)
        env = HikingEnv(cfg, trails=trails)
        env.worker_process = WorkerProcess()
        env = env if self.wrap is None else self.wrap(env)
        return TransformedEnv(env, Compose(RewardSum(), StepCounter()))


class WorkerEnvs:
    """The workers' env state as seen from the main process (``collector.workers > 1``).

    Args:
        collector: the :class:`~torchrl.collectors.MultiSyncCollector` over :class:`EnvSlice` envs.
        env: the main process's ``HikingEnv`` of all ``N`` worlds (not stepped): mirrors the workers.
    """

    def __init__(self, collector: MultiSyncCollector, env: HikingEnv) -> None:
        self.collector, self.env = collector, env
        self.workers = collector.num_workers
        self.n = env.cfg.num_envs // self.workers
        # each world keeps its category for good: read once
        env.world_category[:] = np.concatenate(collector.get_distant_attr(f"{BASE_ENV}.world_category"))

    def call(self, path: str, *args) -> list:
        """``path(*args)`` on every worker's collector (``path`` from it: ``"env.base_env.<method>"``,
        ``"policy.<method>"``); returns the K results."""
        return self.collector.map_fn(path, [args] * self.workers)

    def pull(self) -> None:
        """Mirror the workers' env state into the main env: curriculum levels (N,) concatenated in
        worker order, counters summed (``global_steps``: the workers step in lockstep, worker 0's),
        each worker's state (its env's, and its torch generator's as ``"torch_rng"``) kept in
        ``env.slice_states``."""
        states = self.call(f"{BASE_ENV}.state_dict")
        for state, rng in zip(states, self.call(f"{PROCESS}.rng_state"), strict=True):
            state["torch_rng"] = rng
        env = self.env
        env.curriculum.levels = np.concatenate([s["curriculum"]["levels"] for s in states]).astype(np.int64)
        env.global_steps = int(states[0]["global_steps"])
        env.diverged_total = sum(int(s["diverged_total"]) for s in states)
        env.bad_action_total = sum(int(s.get("bad_action_total", 0)) for s in states)
        env.slice_states = states

    def push(self, reseed: bool) -> None:
        """Hand the main env's state to the workers and reset their worlds (a resumed run): worker k
        gets levels ``k N/K .. (k+1) N/K - 1``, the step counter, and its own saved state's random
        streams (env and torch) and counters (``env.slice_states``); with ``reseed`` (another K than
        the checkpoint's) its random streams stay the fresh ones of ``seed + k`` and worker 0 takes
        the counters."""
        env, n = self.env, self.n
        saved = None if reseed else env.slice_states
        fresh = self.call(f"{BASE_ENV}.state_dict")
        states = []
        for k in range(self.workers):
            state = dict(saved[k]) if saved is not None else {
                "rng": fresh[k]["rng"],
                "diverged_total": env.diverged_total if k == 0 else 0,
                "bad_action_total": env.bad_action_total if k == 0 else 0}
            state["curriculum"] = {"levels": env.curriculum.levels[k * n:(k + 1) * n].copy()}
            state["global_steps"] = env.global_steps
            states.append((state,))
        self.collector.map_fn(f"{BASE_ENV}.load_state_dict", states)
        if saved is not None:
            self.collector.map_fn(f"{PROCESS}.set_rng_state", [(s["torch_rng"],) for s in saved])
        self.collector.reset()  # the worlds start on the handed levels and random streams
        self.pull()


def _leave_signals_to_main() -> None:
    """A worker's first act: ignore SIGINT and SIGTERM. Ctrl-C reaches the whole process group;
    the main process stops the run after its checkpoint (GracefulStop) and then shuts the workers
    down, which it could not do if they had died mid-batch. A worker whose main process is gone
    ends on its closed pipe."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def make_worker_collector(cfg: HikingEnvConfig, workers: int, wrap, policy, frames_per_batch: int,
                          total_frames: int, torch_threads: int, **kwargs) -> MultiSyncCollector:
    """A :class:`~torchrl.collectors.MultiSyncCollector` over ``workers`` :class:`EnvSlice` envs
    whose batches are ``[N, T]`` (the slices concatenated along the worlds).

    ``torch_threads`` are split over the workers (at least 1 each: the policy's inference there);
    the main process keeps its own torch thread count.
    """
    envs = [EnvSlice(cfg, k, workers, wrap) for k in range(workers)]
    # a spawned worker waits this long (torchrl's default: 60 s) for the policy's first weights,
    # which come after every worker has built its worlds: on a loaded machine that takes longer
    os.environ.setdefault("WEIGHT_SYNC_TIMEOUT", "600")
    return MultiSyncCollector(envs, policy, frames_per_batch=frames_per_batch, total_frames=total_frames,
                              cat_results=0, use_buffers=True, storing_device=cfg.device,
                              num_threads=torch.get_num_threads(), num_sub_threads=max(1, int(torch_threads) // workers),
                              init_fn=_leave_signals_to_main, **kwargs)
