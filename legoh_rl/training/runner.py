"""The training loop every recipe shares: run folder, resume, collection, checkpoints and logs.

A recipe describes its algorithm as a :class:`Trainer` (what it collects with, how one batch
updates it, what its checkpoint holds) and hands it to :func:`train`. Everything else lives here
once:

* the run folder is checked and locked (:func:`~legoh_rl.training.run_dir.open_run_dir`) and
  SIGINT/SIGTERM stop the run after a checkpoint (:class:`~legoh_rl.training.interrupt.GracefulStop`);
* a torchrl :class:`~torchrl.collectors.Collector` gathers ``env.num_envs x
  collector.steps_per_env`` steps per iteration until ``collector.total_frames`` run frames,
  through torchrl's ``RewardSum`` and ``StepCounter`` (episode return and length for the logs);
* every ``checkpoint.every`` iterations, and at the end, ``last.pt`` is written atomically with
  the trainer's state, the env (curriculum, randomisation), the RNG states, the counters, the
  resolved config and the provenance (``experiment``, ``stage`` in the meta block); the logs are
  flushed right after, so they hold exactly what the checkpoint covers (:class:`RunLog`);
* every ``logger.video_every`` iterations (0: never), a video of the checkpoint's policy, one
  robot per category at the worlds' median level (:func:`~legoh_rl.training.videos.policy_video`),
  goes to ``<checkpoint.dir>/videos/`` and the wandb run.
"""

from __future__ import annotations

import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import ExplorationType
from tqdm import tqdm

from legoh_rl.training.checkpoint import rng_state, save_checkpoint
from legoh_rl.training.interrupt import GracefulStop
from legoh_rl.training.run_dir import open_run_dir
from legoh_rl.training.run_log import RunLog
from legoh_rl.training.videos import policy_video

__all__ = ["Trainer", "train", "provenance", "finish"]


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

    def before_collect(self) -> None:  # noqa: B027 (optional hook: most trainers have no schedule)
        """Set what the next batch is collected with (schedules over ``frames`` / ``iteration``)."""

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
    with open_run_dir(cfg.checkpoint.dir, cfg.checkpoint.resume, bool(cfg.checkpoint.get("overwrite", False))), \
            GracefulStop() as stop:
        return _loop(cfg, build(cfg), stop)


def _loop(cfg: DictConfig, t: Trainer, stop: GracefulStop) -> dict:
    ckpt_dir = Path(cfg.checkpoint.dir)
    run = RunLog(cfg, ckpt_dir, t.run_id, t.frames)
    frames_per_batch = cfg.env.num_envs * cfg.collector.steps_per_env
    remaining = int(cfg.collector.total_frames) - t.frames
    if remaining < frames_per_batch:
        print(f"nothing left to train: {t.frames} of {cfg.collector.total_frames} frames done")
        return {"iteration": t.iteration, "frames": t.frames}
    t.before_collect()
    # torchrl's episode counters: the return and length of each ended episode, for the logs
    collect_env = TransformedEnv(t.collect_env, Compose(RewardSum(), StepCounter()))
    collector = Collector(collect_env, t.behaviour, frames_per_batch=frames_per_batch, total_frames=remaining,
                          exploration_type=ExplorationType.RANDOM, **t.collector_kwargs)

    def checkpoint() -> Path:
        path = save_checkpoint(ckpt_dir / "last.pt", {
            "meta": {**t.meta, **provenance(cfg)}, **t.state_dict(), "env": t.env.state_dict(), "rng": rng_state(),
            "iteration": t.iteration, "frames": t.frames, "run_id": run.run_id,
            "config": OmegaConf.to_container(cfg, resolve=True),
        })
        run.flush()  # the logs hold what the checkpoint covers
        return path

    video_every = int(cfg.logger.get("video_every") or 0)  # 0: no training videos
    summary: dict = {}
    bar = tqdm(total=remaining, unit="frames", desc=t.desc)
    collected = time.perf_counter()
    for data in collector:
        started = time.perf_counter()
        collect_s = started - collected
        stats = t.update(data)
        collector.update_policy_weights_()
        t.iteration += 1
        t.frames += data.numel()
        bar.update(data.numel())
        stats["train/update_s"] = time.perf_counter() - started
        stats["train/collect_s"] = collect_s
        t.before_collect()  # before the checkpoint, so that it holds the settings its resume collects with
        stats = run.log(t.iteration, t.frames, data, t.env, stats)
        bar.set_postfix(t.postfix(stats))
        if t.iteration % cfg.checkpoint.every == 0:
            checkpoint()
        if video_every and t.iteration % video_every == 0:
            path = checkpoint() if t.iteration % cfg.checkpoint.every else ckpt_dir / "last.pt"
            run.video(policy_video(path, ckpt_dir / "videos" / f"iteration{t.iteration:06d}.mp4",
                                   t.env.trails.categories, int(np.median(t.env.curriculum.levels)),
                                   seconds=float(cfg.logger.get("video_seconds", 4.0))), t.frames)
        summary = {"iteration": t.iteration, "frames": t.frames, **stats}
        collected = time.perf_counter()
        if stop.signum is not None:
            summary["interrupted"] = stop.signum
            break
    bar.close()
    collector.shutdown()
    summary["checkpoint"] = str(checkpoint())
    run.close()
    return summary


def finish(summary: dict) -> None:
    """A recipe's last words: what was trained and where it went; exit 128 + signal when a signal
    stopped the run (so a schedule around it stops too)."""
    stage = f" (stage {summary['stage']})" if summary.get("stage") else ""
    print(f"done{stage}: {summary.get('iteration')} iterations, {summary.get('frames')} frames; "
          f"checkpoint {summary.get('checkpoint')}" + (f"; policy {summary['policy']}" if summary.get("policy") else ""))
    if summary.get("interrupted"):
        sys.exit(128 + int(summary["interrupted"]))
