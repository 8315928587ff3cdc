"""Per-iteration bookkeeping shared by the training recipes."""

from __future__ import annotations

import json
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase

from legoh_rl.training.logging import MetricsFile, make_logger, trim_csv_logs
from legoh_rl.training.stats import (
    curriculum_stats,
    ending_stats,
    episode_stats,
    return_stats,
    reward_term_stats,
    split_episode_stats,
)

__all__ = ["RunLog", "read_metrics", "training_hours"]


class RunLog:
    """The logger (wandb offline / CSV) and ``metrics.jsonl`` of one training run.

    Rows are held back until :meth:`flush`, which the recipes call right after each checkpoint:
    the logs then hold exactly the steps a checkpoint covers, so a killed and resumed run logs
    each step once (wandb cannot take back a step; the files are also trimmed on resume for a
    kill between the checkpoint and the flush).

    Args:
        cfg: the recipe config (its ``logger`` section; recorded as the run's config).
        run_dir: the run's checkpoint folder (logs go to ``run_dir/logs``).
        run_id: the wandb run to continue after a resume.
        start_frames: frames already done when this process started (for the fps figure).
    """

    def __init__(self, cfg: DictConfig, run_dir: Path, run_id: str | None, start_frames: int) -> None:
        lcfg = cfg.logger
        self.logger = make_logger(lcfg.backend, lcfg.exp_name, str(run_dir / "logs"), lcfg.project, lcfg.online,
                                  run_id, OmegaConf.to_container(cfg, resolve=True),
                                  group=lcfg.get("group") or cfg.get("experiment_name"))
        self.run_id = getattr(getattr(self.logger, "experiment", None), "id", run_id)
        self.metrics = MetricsFile(run_dir / "metrics.jsonl", resume_step=start_frames if start_frames else None)
        if start_frames:
            trim_csv_logs(run_dir / "logs", start_frames)
        self.pending: list[tuple[int, dict]] = []
        self.every = int(lcfg.log_every)
        self.start_frames = start_frames
        self.start = time.perf_counter()
        self._env_time: dict[str, float] = {}  # the env's time_spent at the last log

    def log(self, iteration: int, frames: int, data: TensorDictBase, env, stats: dict,
            figures: dict | None = None) -> dict:
        """Add reward-term, episode, curriculum and env figures to ``stats``; queue them when due.

        ``figures``: the env's figures taken earlier (:meth:`env_figures`), for a loop that
        collects the next batch while this one is logged (``collector.overlap``); ``None``: read
        ``env`` now.
        """
        stats.update(reward_term_stats(data))
        stats.update(episode_stats(data))
        stats.update(return_stats(data))
        stats.update(ending_stats(data))
        stats.update(split_episode_stats(data, tuple(env.trails.categories)))
        stats.update(self.env_figures(env) if figures is None else figures)
        stats.update({
            "train/frames": frames,
            "train/fps_total": (frames - self.start_frames) / (time.perf_counter() - self.start),
        })
        if iteration % self.every == 0:
            self.pending.append((frames, dict(stats)))
        return stats

    def env_figures(self, env) -> dict:
        """The figures read from the env's state: curriculum levels per category, the counters and
        the seconds the env spent since the last call (``env/<part>_s``)."""
        categories = tuple(env.trails.categories)
        figures = curriculum_stats(env.curriculum.levels, env.world_category, categories)
        figures.update({
            "curriculum/mean_level": float(env.curriculum.levels.mean()),
            "env/diverged_total": env.diverged_total,
            "env/bad_action_total": env.bad_action_total,
            # env steps per world, against which domain_rand's action delay switches on
            "env/global_steps": env.global_steps,
            "env/action_delay_steps": env.randomizer.delay_steps(env.global_steps),
        })
        figures.update(self._env_seconds(env))
        return figures

    def _env_seconds(self, env) -> dict:
        """``env/<part>_s``: seconds the env spent in ``step``, its physics and resets since the
        last log (none when this process's env did not step: collection in worker processes)."""
        spent = dict(getattr(env, "time_spent", {}))
        delta = {k: v - self._env_time.get(k, 0.0) for k, v in spent.items()}
        self._env_time = spent
        if not any(delta.values()):
            return {}
        return {f"env/{k}_s": v for k, v in delta.items()}

    def flush(self) -> None:
        """Write the queued rows (one logger call each) to the logger and ``metrics.jsonl``."""
        for frames, stats in self.pending:
            self.logger.log_metrics(stats, step=frames)
            self.metrics.write(frames, stats)
        self.pending.clear()
        for f in getattr(getattr(self.logger, "experiment", None), "files", {}).values():  # CSVLogger's open files
            f.flush()

    def video(self, path: Path | None, frames: int) -> None:
        """Log the video at ``path`` (None: nothing rendered) to wandb, tagged with the run's
        ``frames``; the CSV logger keeps the file where it is."""
        exp = getattr(self.logger, "experiment", None)
        if path is None or exp is None or not hasattr(exp, "log"):
            return
        import wandb

        exp.log({"train/video": wandb.Video(str(path), format="mp4"), "train/video_frames": frames})

    def close(self) -> None:
        """Flush, then finish the wandb run (writes its offline files)."""
        self.flush()
        exp = getattr(self.logger, "experiment", None)
        if exp is not None and hasattr(exp, "finish"):
            exp.finish()


def read_metrics(path: str | Path) -> list[dict]:
    """The rows of a run's ``metrics.jsonl`` (one dict per logged iteration, ``step`` = env steps)."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def training_hours(rows: list[dict]) -> list[float]:
    """Hours of training up to and including each row (one row per iteration): the running sum of
    the iterations' ``train/iteration_s`` (from one batch in hand to the next: with
    ``collector.overlap`` collection and update overlap), or of their ``train/collect_s`` +
    ``train/update_s`` for rows logged before it existed; start-ups not counted. A row logged
    before ``train/collect_s`` existed counts its frames over the run's rate at that row
    (``train/fps_total``, the mean since its session started).

    Raises:
        ValueError: a row with neither (names its step).
    """
    out, total = [], 0.0
    for i, r in enumerate(rows):
        if r.get("train/iteration_s") is not None:
            total += float(r["train/iteration_s"])
        elif r.get("train/collect_s") is not None and r.get("train/update_s") is not None:
            total += float(r["train/collect_s"]) + float(r["train/update_s"])
        elif r.get("train/fps_total"):
            batch = (r["step"] - rows[i - 1]["step"] if i > 0
                     else rows[1]["step"] - r["step"] if len(rows) > 1 else r["step"])
            total += batch / float(r["train/fps_total"])
        else:
            raise ValueError(f"row at step {r.get('step')} has no train/collect_s and train/update_s (nor "
                             "train/fps_total): training hours need a run that logged its iteration times")
        out.append(total / 3600.0)
    return out
