"""The training loop every recipe shares: run folder, resume, collection, checkpoints and logs.

A recipe describes its algorithm as a :class:`Trainer` (what it collects with, how one batch
updates it, what its checkpoint holds) and hands it to :func:`train`. Everything else lives here
once:

* the run folder is checked and locked (:func:`~legoh_rl.training.run_dir.open_run_dir`) and
  SIGINT/SIGTERM stop the run after a checkpoint (:class:`~legoh_rl.training.interrupt.GracefulStop`);
* a torchrl :class:`~torchrl.collectors.Collector` gathers ``env.num_envs x
  collector.steps_per_env`` steps per iteration until ``collector.total_frames`` run frames,
  through torchrl's ``RewardSum`` and ``StepCounter`` (episode return and length for the logs);
  with ``collector.workers=K > 1``, a :class:`~torchrl.collectors.MultiSyncCollector` over K
  processes, each stepping ``N / K`` of the worlds (:mod:`legoh_rl.training.workers`: their env
  state reaches the logs and checkpoints through the trainer's ``env``, which mirrors it); with
  ``collector.backend=ray``, torchrl's :class:`~torchrl.collectors.distributed.RayCollector` over K
  Ray actors, on this machine or a cluster's nodes, with the same slices and the same mirroring
  (:mod:`legoh_rl.training.ray_collection`);
* with ``collector.overlap=true`` (one process), the next batch is collected in a thread, by a
  copy of the policy as it was before the update, while the update runs on the current one
  (:func:`_overlapped_loop`): iterations where a checkpoint, snapshot or video is due collect
  the next batch after it instead, so every checkpoint is taken between batches;
* the run's config records the device it computes on (``device``, resolved from ``auto``:
  :func:`~legoh_rl.training.device.resolve_device`);
* every ``checkpoint.every`` iterations, and at the end, ``last.pt`` is written atomically with
  the trainer's state, the env (curriculum, randomisation), the RNG states, the counters, the
  resolved config and the provenance (``experiment``, ``stage`` in the meta block); the logs are
  flushed right after, so they hold exactly what the checkpoint covers (:class:`RunLog`);
* every ``checkpoint.snapshot_every`` iterations (0: never), a slim copy of the policy
  (:func:`~legoh_rl.training.checkpoint.export_policy`) goes to
  ``<checkpoint.dir>/snapshots/frames<run frames>.pt``: the learning curve's points, evaluated
  later on the benchmark (``recipes/evaluate.py``); with ``checkpoint.ema_decay`` the trainer's
  weight average (:mod:`~legoh_rl.training.weight_average`, updated after every iteration) goes
  beside it to ``snapshots/ema/``; a run that reaches ``collector.total_frames`` also snapshots
  its last iteration when that was not a multiple (the trained policy's end is a curve point too);
* every ``logger.video_every`` iterations (0: never), a video of the checkpoint's policy, one
  robot per category at the worlds' median level (:func:`~legoh_rl.training.videos.policy_video`),
  goes to ``<checkpoint.dir>/videos/`` and the wandb run.
"""

from __future__ import annotations

import copy
import sys
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf, open_dict
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import ExplorationType
from tqdm import tqdm

from legoh_rl.training import ray_collection  # works without Ray (an optional extra)
from legoh_rl.training.checkpoint import CheckpointError, export_policy, rng_state, save_checkpoint
from legoh_rl.training.device import resolve_device
from legoh_rl.training.interrupt import GracefulStop
from legoh_rl.training.prefetch import Prefetch, next_batch, thread_local_sampling_mode
from legoh_rl.training.run_dir import open_run_dir
from legoh_rl.training.run_log import RunLog
from legoh_rl.training.videos import policy_video
from legoh_rl.training.weight_average import PolicyAverage
from legoh_rl.training.workers import WorkerEnvs, check_workers, make_worker_collector

__all__ = ["Trainer", "train", "provenance", "finish", "collector_workers", "collector_backend", "collector_overlap",
           "weights_shared"]


class Trainer(ABC):
    """One training algorithm, built (and restored on resume) by its recipe.

    Attributes:
        env: the base :class:`~legoh_rl.envs.HikingEnv` (its state is checkpointed; curriculum and
            episode figures are logged from it).
        collect_env: what the collector steps (``env`` itself, or ``env`` under transforms).
        behaviour: the policy module the collector runs.
        meta: the checkpoint's meta block (what a loader must match: robot, layout, kind, ...).
        iteration, frames: counters (restored on resume); ``run_id``: the logger run to continue.
        desc: the progress bar's label.
        collector_kwargs: extra keyword arguments of the collector.
        device: where the networks, losses and updates are (the resolved ``device`` setting).
        average: the EMA of the policy's weights that snapshots also write (``checkpoint.ema_decay``),
            or ``None``; the recipe builds it, checkpoints it in :meth:`state_dict` and restores it.
        env_wrap: ``collect_env = env_wrap(env)`` (``None``: ``collect_env`` is ``env``); with
            ``collector.workers > 1`` (or ``collector.backend=ray``) each worker wraps its own slice
            of the worlds with it, so it must be picklable (a module-level function or a
            ``functools.partial`` of one).
    """

    env = None
    collect_env = None
    behaviour = None
    meta: dict = {}
    iteration: int = 0
    frames: int = 0
    run_id: str | None = None
    desc: str = "training"
    collector_kwargs: dict = {}
    device: torch.device = torch.device("cpu")
    env_wrap: Callable | None = None
    average: PolicyAverage | None = None

    #: whether ``collector.overlap`` may collect this trainer's next batch during its update: the
    #: update draws no random numbers from torch's global generator (the collecting thread's), and
    #: :meth:`overlap_policy` gives a policy the update does not touch
    overlap_ready: bool = False

    def overlap_policy(self) -> torch.nn.Module:
        """``collector.overlap``: the module the collector runs, a copy of :attr:`behaviour` that
        :meth:`refresh_overlap_policy` brings up to date between batches."""
        return copy.deepcopy(self.behaviour)

    def refresh_overlap_policy(self, policy: torch.nn.Module) -> None:
        """Copy :attr:`behaviour`'s parameters and buffers into ``policy`` (in place: the collector
        holds it) and any setting :meth:`before_collect` gave the behaviour."""
        TensorDict.from_module(policy).data.update_(TensorDict.from_module(self.behaviour).data)

    def before_collect(self) -> None:  # noqa: B027 (optional hook: most trainers have no schedule)
        """Set what the next batch is collected with (schedules over ``frames`` / ``iteration``)."""

    def collection_settings(self) -> dict[str, float]:
        """The logged figures of what :meth:`before_collect` just set (``{"train/<name>": value}``):
        the runner takes them then and logs them with the update on that batch, which under
        ``collector.overlap`` runs after the next batch's settings are already set."""
        return {}

    def sync_workers(self, workers: WorkerEnvs, first: bool) -> None:  # noqa: B027 (optional hook)
        """``collector.workers > 1`` (or ``collector.backend=ray``): tell the worker processes what
        :meth:`before_collect` set for the next batch (``workers.call(path, *args)`` runs a method of
        each worker's collector: ``"env.base_env.<method>"``, ``"policy.<method>"``); ``first``:
        before the first batch."""

    @abstractmethod
    def update(self, data) -> dict[str, float]:
        """Learn from one collected ``[N, T]`` batch (``self.iteration`` batches came before it);
        return the iteration's diagnostics (``"loss/..."``, ``"train/..."``)."""

    @abstractmethod
    def state_dict(self) -> dict:
        """The algorithm's part of the checkpoint (networks, optimisers, ...)."""

    def postfix(self, stats: dict) -> dict[str, str]:
        """Figures shown on the progress bar."""
        return {"sr": f"{stats.get('episode/success', float('nan')):.0f}"}


def provenance(cfg: DictConfig) -> dict:
    """``{"experiment": name, "stage": name}`` of a run (``None`` each for a run from the plain config)."""
    return {"experiment": cfg.get("experiment_name"), "stage": cfg.get("stage_name")}


def train(cfg: DictConfig, validate: Callable[[DictConfig], None], build: Callable[[DictConfig], Trainer]) -> dict:
    """Validate ``cfg``, open its run folder, build the trainer and train it to ``collector.total_frames``.

    Returns:
        a summary of the last iteration: ``iteration``, ``frames``, the logged figures,
        ``checkpoint`` (the path written last) and, when SIGINT/SIGTERM stopped the run after its
        checkpoint, ``interrupted`` (the signal number).
    """
    validate(cfg)
    collector_overlap(cfg)  # before any work: the settings it needs
    snapshots = cfg.checkpoint.get("snapshot_every", 0)
    if snapshots is not None and (isinstance(snapshots, bool) or not isinstance(snapshots, int) or snapshots < 0):
        raise ValueError(f"checkpoint.snapshot_every must be an integer >= 0 (iterations; 0: none), got {snapshots!r}")
    cfg = copy.deepcopy(cfg)
    with open_dict(cfg):  # the run's config (logs, checkpoint) records the device it ran on: "auto" resolved
        cfg.device = str(resolve_device(cfg.get("device")))
    with open_run_dir(cfg.checkpoint.dir, cfg.checkpoint.resume, bool(cfg.checkpoint.get("overwrite", False))), \
            GracefulStop() as stop:
        t = build(cfg)
        workers = collector_workers(cfg)
        return _loop(cfg, t, stop, _check_slices(cfg, t, workers, _pooled(cfg, workers)))


class _BatchSettings:
    """Each collected batch's :meth:`Trainer.collection_settings`, oldest first: taken when
    :meth:`Trainer.before_collect` sets them, handed to the log row of the update on that batch."""

    def __init__(self, t: Trainer) -> None:
        self.t, self.pending = t, deque()

    def set_next(self) -> None:
        """The next batch's settings: :meth:`Trainer.before_collect`, then its figures kept."""
        self.t.before_collect()
        self.pending.append(dict(self.t.collection_settings()))

    def of_batch(self) -> dict[str, float]:
        """The figures of the oldest batch not yet updated on (the one the update just used)."""
        return self.pending.popleft()


def _loop(cfg: DictConfig, t: Trainer, stop: GracefulStop, reseed: bool | None) -> dict:
    ckpt_dir = Path(cfg.checkpoint.dir)
    run = RunLog(cfg, ckpt_dir, t.run_id, t.frames)
    frames_per_batch = cfg.env.num_envs * cfg.collector.steps_per_env
    remaining = int(cfg.collector.total_frames) - t.frames
    if remaining < frames_per_batch:
        print(f"nothing left to train: {t.frames} of {cfg.collector.total_frames} frames done")
        return {"iteration": t.iteration, "frames": t.frames}
    overlap = collector_overlap(cfg, t)
    settings = _BatchSettings(t)
    settings.set_next()
    threads = torch.get_num_threads()
    policy = t.overlap_policy() if overlap else None
    collector, pool = _collector(cfg, t, frames_per_batch, remaining, reseed, policy)
    ends = _IterationEnds(cfg, t, run, ckpt_dir)
    bar = tqdm(total=remaining, unit="frames", desc=t.desc)
    try:
        if overlap:
            summary = _overlapped_loop(t, settings, collector, policy, ends, bar, stop)
        else:
            summary = _sequential_loop(t, settings, collector, pool, ends, bar, stop)
    finally:
        bar.close()
        collector.shutdown()
        torch.set_num_threads(threads)  # torchrl's multi-process collector changes the main process's count
    summary["checkpoint"] = str(ends.finish(summary))
    run.close()
    return summary


class _IterationEnds:
    """What ends every iteration of either loop: the log row, and when due the checkpoint, the
    policy snapshot and the video."""

    def __init__(self, cfg: DictConfig, t: Trainer, run: RunLog, ckpt_dir: Path) -> None:
        self.cfg, self.t, self.run, self.dir = cfg, t, run, ckpt_dir
        self.video_every = int(cfg.logger.get("video_every") or 0)  # 0: no training videos
        self.snapshot_every = int(cfg.checkpoint.get("snapshot_every") or 0)  # 0: none
        self.every = int(cfg.checkpoint.every)

    def checkpoint(self) -> Path:
        t, cfg = self.t, self.cfg
        path = save_checkpoint(self.dir / "last.pt", {
            "meta": {**t.meta, **provenance(cfg)}, **t.state_dict(), "env": t.env.state_dict(), "rng": rng_state(),
            "iteration": t.iteration, "frames": t.frames, "run_id": self.run.run_id,
            "config": OmegaConf.to_container(cfg, resolve=True),
        })
        self.run.flush()  # the logs hold what the checkpoint covers
        return path

    def snapshot(self) -> Path:
        """Write the policy of ``last.pt`` (which must hold the current iteration) to
        ``snapshots/frames<N>.pt``, and the weight average's to ``snapshots/ema/`` when the run keeps one."""
        t, ckpt_dir = self.t, self.dir
        name = f"frames{t.frames:09d}.pt"
        path = export_policy(ckpt_dir / "last.pt", ckpt_dir / "snapshots" / name)
        if t.average is not None:
            export_policy(ckpt_dir / "last.pt", ckpt_dir / "snapshots" / "ema" / name,
                          provenance={"weights": f"ema {t.average.decay}"}, weights=t.average.policy_state())
        return path

    def finish(self, summary: dict) -> Path:
        """The run's last checkpoint; a run that reached ``collector.total_frames`` (not stopped by a
        signal) also gets its end snapshot when snapshots are on and its last iteration wrote none,
        so the trained policy's end is evaluated like every snapshot before it."""
        path = self.checkpoint()
        if self.snapshot_every and self.t.iteration % self.snapshot_every and "interrupted" not in summary:
            self.snapshot()
        return path

    def due(self, iteration: int) -> bool:
        """Whether iteration ``iteration``'s end writes anything from the run's state (checkpoint,
        snapshot or video): the overlapped loop collects nothing beside such an iteration's update."""
        return any(every and iteration % every == 0 for every in (self.every, self.snapshot_every, self.video_every))

    def close(self, data, stats: dict, figures: dict | None = None) -> dict:
        """Log the iteration ``t.iteration`` just ended (``figures``: the env's, taken earlier),
        then write what is due; returns the logged figures."""
        t, ckpt_dir = self.t, self.dir
        stats = self.run.log(t.iteration, t.frames, data, t.env, stats, figures)
        if t.iteration % self.every == 0:
            self.checkpoint()
        if self.snapshot_every and t.iteration % self.snapshot_every == 0:  # the policy as it was, for later evaluation
            if t.iteration % self.every:
                self.checkpoint()
            self.snapshot()
        if self.video_every and t.iteration % self.video_every == 0:
            path = self.checkpoint() if t.iteration % self.every else ckpt_dir / "last.pt"
            self.run.video(policy_video(path, ckpt_dir / "videos" / f"iteration{t.iteration:06d}.mp4",
                                        t.env.trails.categories, int(np.median(t.env.curriculum.levels)),
                                        seconds=float(self.cfg.logger.get("video_seconds", 4.0))), t.frames)
        return stats


def _sequential_loop(t: Trainer, settings: _BatchSettings, collector, pool: WorkerEnvs | None, ends: _IterationEnds,
                     bar, stop) -> dict:
    """Collect a batch, update on it, in turn."""
    summary: dict = {}
    push = not weights_shared(collector, t.behaviour)
    collected = batch_at = time.perf_counter()
    for data in collector:
        now = time.perf_counter()
        iteration_s, batch_at = now - batch_at, now  # from the last batch in hand to this one
        data = data.copy()  # a new structure over the same tensors: the update's new keys stay out of the buffer
        if pool is not None:
            pool.pull()  # the workers' curriculum and counters, for the logs and the checkpoint
        started = time.perf_counter()
        collect_s = started - collected
        stats = {**t.update(data), **settings.of_batch()}
        if t.average is not None:  # reads the trained weights only: training is unchanged
            t.average.update()
        if push:  # workers or Ray: the trained policy's weights, sent to every worker
            collector.update_policy_weights_()
        t.iteration += 1
        t.frames += data.numel()
        bar.update(data.numel())
        stats["train/update_s"] = time.perf_counter() - started
        stats["train/collect_s"] = collect_s
        stats["train/iteration_s"] = iteration_s
        settings.set_next()  # before the checkpoint, so that it holds the settings its resume collects with
        if pool is not None:
            t.sync_workers(pool, first=False)
        stats = ends.close(data, stats)
        bar.set_postfix(t.postfix(stats))
        summary = {"iteration": t.iteration, "frames": t.frames, **stats}
        collected = time.perf_counter()
        if stop.signum is not None:
            summary["interrupted"] = stop.signum
            break
    return summary


def _overlapped_loop(t: Trainer, settings: _BatchSettings, collector, policy: torch.nn.Module, ends: _IterationEnds,
                     bar, stop) -> dict:
    """``collector.overlap``: batch ``k + 1`` is collected in a thread, by ``policy`` holding the
    weights from before update ``k``, while update ``k`` runs; an iteration whose end is due to
    write the run's state (:meth:`_IterationEnds.due`) collects batch ``k + 1`` after that, with the
    weights of update ``k``, so checkpoints lie between batches and a resumed run collects as the
    uninterrupted one would. The env's figures are taken between batches; ``train/collect_s`` is
    the collection's own time, ``train/wait_s`` the update's wait for it, ``train/iteration_s``
    the time from one batch in hand to the next.

    A signal during an overlapped update ends the run after the batch being collected beside it:
    that batch is dropped (its frames are not counted) and the checkpoint holds the env as it left it.
    """
    thread_local_sampling_mode()  # the update's losses set their deterministic mode in their own thread only
    summary: dict = {}
    iterator = iter(collector)
    batch_at = time.perf_counter()
    t.refresh_overlap_policy(policy)  # the weights (and settings) the trainer starts or resumes with
    data, collect_s = next_batch(iterator)
    while data is not None:
        now = time.perf_counter()
        iteration_s, batch_at = now - batch_at, now
        n = data.numel()
        figures = ends.run.env_figures(t.env)  # before the env moves on to the next batch
        k, frames = t.iteration, t.frames
        t.iteration, t.frames = k + 1, frames + n  # the next batch's settings, at the counters it is collected at
        settings.set_next()
        t.iteration, t.frames = k, frames
        overlapped = not ends.due(k + 1) and stop.signum is None
        if overlapped:
            t.refresh_overlap_policy(policy)  # the weights before this update
            prefetch = Prefetch(iterator)
        started = time.perf_counter()
        try:
            stats = {**t.update(data), **settings.of_batch()}
            update_s = time.perf_counter() - started
        finally:
            if overlapped:  # never leave the thread running
                waiting = time.perf_counter()
                prefetched = prefetch.result()
                wait_s = time.perf_counter() - waiting
        if t.average is not None:  # reads the trained weights only: training is unchanged
            t.average.update()
        t.iteration, t.frames = k + 1, frames + n
        bar.update(n)
        stats.update({"train/update_s": update_s, "train/collect_s": collect_s, "train/iteration_s": iteration_s,
                      "train/overlapped": float(overlapped)})
        if overlapped:
            stats["train/wait_s"] = wait_s
        stats = ends.close(data, stats, figures)
        bar.set_postfix(t.postfix(stats))
        summary = {"iteration": t.iteration, "frames": t.frames, **stats}
        if stop.signum is not None:
            summary["interrupted"] = stop.signum
            break
        if overlapped:
            data, collect_s = prefetched
        else:
            t.refresh_overlap_policy(policy)  # this update's weights
            data, collect_s = next_batch(iterator)
    return summary


def _collector(cfg: DictConfig, t: Trainer, frames_per_batch: int, total_frames: int, reseed: bool | None,
               policy: torch.nn.Module | None = None):
    """``(collector, pool)``: torchrl's ``Collector`` on the trainer's own env (``pool`` None), or,
    when workers step the worlds, a ``MultiSyncCollector`` of K processes or a ``RayCollector`` of
    K actors with the :class:`WorkerEnvs` that mirrors their env state (``reseed``: from
    :func:`_check_slices`; ``None`` for a fresh run). ``policy``: ``collector.overlap``'s copy of
    the behaviour, which the (one-process) collector then runs, handing out a new batch each time."""
    workers = collector_workers(cfg)
    kwargs = dict(exploration_type=ExplorationType.RANDOM, **t.collector_kwargs)
    if not _pooled(cfg, workers):
        # torchrl's episode counters: the return and length of each ended episode, for the logs
        collect_env = TransformedEnv(t.collect_env, Compose(RewardSum(), StepCounter()))
        # return_same_td: the collector hands out its own rollout buffer instead of a clone of it
        # (the loop is done with a batch before the next is collected; _loop takes a shallow copy
        # so the entries an update adds stay out of the buffer). The clone copied every depth
        # stack twice (root and next), ~0.2 s of a student's 0.6 s collection (BENCHMARKS.md).
        # collector.overlap collects the next batch while the update reads this one: a new one each.
        return Collector(collect_env, t.behaviour if policy is None else policy, frames_per_batch=frames_per_batch,
                         total_frames=total_frames, return_same_td=policy is None, **kwargs), None
    if collector_backend(cfg) == "ray":  # K Ray actors, each its slice (legoh_rl/training/ray_collection.py)
        collector = ray_collection.make_ray_collector(
            t.env.cfg, workers, t.env_wrap, t.behaviour, frames_per_batch, total_frames,
            ray_collection.ray_options(cfg.collector.get("ray")), t.device, **kwargs)
    else:  # K processes, each its slice of the worlds (legoh_rl/training/workers.py)
        collector = make_worker_collector(t.env.cfg, workers, t.env_wrap, t.behaviour, frames_per_batch, total_frames,
                                          int(cfg.get("torch_threads") or 1), **kwargs)
    try:
        pool = WorkerEnvs(collector, t.env)
        if reseed is None:  # a fresh run: the workers' own initial state
            pool.pull()
        else:  # the workers continue from the checkpoint's state, on freshly reset worlds
            pool.push(reseed=reseed)
        t.sync_workers(pool, first=True)
    except BaseException:
        collector.shutdown()
        raise
    return collector, pool


def weights_shared(collector, policy: torch.nn.Module) -> bool:
    """Whether ``collector`` is a one-process torchrl ``Collector`` that runs ``policy``'s own
    parameters and buffers (the trainer's behaviour on the CPU): pushing the trained weights to it
    would copy every tensor onto itself, ~1% of a student's iteration (BENCHMARKS.md, "Where the DAgger
    iteration goes now").
    Worker processes, Ray actors and a collector holding a copy (another device) return False."""
    inner = getattr(collector, "_policy_w_state_dict", None)
    if not isinstance(collector, Collector) or not isinstance(inner, torch.nn.Module):
        return False
    mine = {x.data_ptr() for x in (*policy.parameters(), *policy.buffers())}
    theirs = [*inner.parameters(), *inner.buffers()]
    return bool(theirs) and all(x.data_ptr() in mine for x in theirs)


def collector_workers(cfg: DictConfig) -> int:
    """``collector.workers`` (1 when absent), checked to divide ``env.num_envs``; the collector's
    backend is checked too (:func:`collector_backend`)."""
    workers = check_workers(cfg.collector.get("workers", 1), int(cfg.env.num_envs))
    collector_backend(cfg)
    return workers


def collector_overlap(cfg: DictConfig, t: Trainer | None = None) -> bool:
    """``collector.overlap`` (false when absent), checked against the rest of the run's settings
    and, given, its trainer.

    Raises:
        ValueError: overlap with worker processes or Ray, on another device than the CPU, with
            torch on more than one thread (``torch_threads``, ``update_threads``), or for a trainer
            that does not allow it (:attr:`Trainer.overlap_ready`); the message names the settings.
    """
    overlap = cfg.collector.get("overlap", False)
    if not isinstance(overlap, bool):
        raise ValueError(f"collector.overlap must be true or false, got {overlap!r}")
    if not overlap:
        return False
    workers, backend = collector_workers(cfg), collector_backend(cfg)
    if workers > 1 or backend != "local":
        raise ValueError("collector.overlap=true collects in a thread of the training process: it needs "
                         f"collector.workers=1 and collector.backend=local (got workers={workers}, backend={backend})")
    device = str(cfg.get("device") or "cpu")
    if device not in ("cpu", "auto") or resolve_device(device).type != "cpu":
        raise ValueError(f"collector.overlap=true is for runs on the CPU (device=cpu), got device={device}")
    threads = {k: cfg.get(k) for k in ("torch_threads", "update_threads") if cfg.get(k) is not None}
    if any(int(v) != 1 for v in threads.values()):
        raise ValueError("collector.overlap=true runs the update and the collection on one torch thread each "
                         f"(their numerics must not depend on which runs when): set torch_threads=1 and "
                         f"update_threads=1 or null, got {', '.join(f'{k}={v}' for k, v in threads.items())}")
    if t is not None and not t.overlap_ready:
        raise ValueError(f"collector.overlap=true: this recipe's trainer ({type(t).__name__}) does not allow "
                         "collecting during its update (its update draws random numbers from the collecting "
                         "thread's generator); set collector.overlap=false")
    return True


def collector_backend(cfg: DictConfig) -> str:
    """``collector.backend`` (``"local"`` when absent), checked; for ``"ray"``, the ``collector.ray``
    section too, and that Ray is installed.

    Raises:
        ValueError: an unknown backend or a bad ``collector.ray`` value (names the setting and value).
        ImportError: ``collector.backend=ray`` without Ray installed (names ``pip install 'legoh-rl[ray]'``).
    """
    backend = ray_collection.collector_backend(cfg.collector)
    if backend == "ray":
        ray_collection.ray_options(cfg.collector.get("ray"))
        ray_collection.import_ray()
    return backend


def _pooled(cfg: DictConfig, workers: int) -> bool:
    """Whether worker processes step the worlds (their env state mirrored into the trainer's env):
    ``collector.workers > 1``, or any number of Ray workers."""
    return workers > 1 or collector_backend(cfg) == "ray"


def _check_slices(cfg: DictConfig, t: Trainer, workers: int, pooled: bool) -> bool | None:
    """Whether the env state ``t.env`` was restored with fits ``workers`` collector processes
    (``pooled``: workers step the worlds, not the main process; the local and Ray backends slice and
    seed alike, so either resumes the other's checkpoint with the same ``workers``).

    Returns:
        ``None`` for a fresh run; for a resumed one, whether the workers' random streams start
        afresh (``collector.allow_new_workers``: the checkpoint's came from another number of workers).

    Raises:
        CheckpointError: the checkpoint's env state was collected by another number of workers
            (names both, and the two ways on).
    """
    saved = t.env.slice_states
    if t.iteration == 0 and t.frames == 0:  # fresh (checkpoint.init only brings networks)
        t.env.slice_states = None
        return None
    have = 1 if saved is None else len(saved)
    same = have == workers and (saved is None) == (not pooled)  # one process <-> one Ray worker: not the same
    if not same and not cfg.collector.get("allow_new_workers", False):
        by = "the main process itself" if saved is None else f"{have} worker process(es)"
        now = f"collector.workers={workers}" + (" (a Ray worker)" if pooled and workers == 1 else "")
        back = "collector.backend=local collector.workers=1" if saved is None else f"collector.workers={have}"
        raise CheckpointError(
            f"checkpoint.resume: the run in {cfg.checkpoint.dir} was collected by {by}, this run "
            f"has {now}: each worker has its own env random stream, which cannot be split or "
            f"merged exactly. Resume with {back}, or pass collector.allow_new_workers=true to go on "
            "with the curriculum levels and counters carried over and the workers' env random streams afresh "
            "(env.seed + k)")
    if not pooled:
        t.env.slice_states = None  # this env is stepped itself from now on
        return False
    return not same


def finish(summary: dict) -> None:
    """A recipe's last words: what was trained and where it went; exit 128 + signal when a signal
    stopped the run (so a schedule around it stops too)."""
    stage = f" (stage {summary['stage']})" if summary.get("stage") else ""
    print(f"done{stage}: {summary.get('iteration')} iterations, {summary.get('frames')} frames; "
          f"checkpoint {summary.get('checkpoint')}" + (f"; policy {summary['policy']}" if summary.get("policy") else ""))
    if summary.get("interrupted"):
        sys.exit(128 + int(summary["interrupted"]))
