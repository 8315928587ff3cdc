"""Loggers: torchrl's WandbLogger (offline by default), CSVLogger when wandb is unusable."""

from __future__ import annotations

import os
import warnings

from torchrl.record.loggers import CSVLogger, Logger

__all__ = ["make_logger", "MetricsFile"]


def make_logger(
    backend: str,
    exp_name: str,
    log_dir: str,
    project: str = "legoh-rl",
    online: bool = False,
    run_id: str | None = None,
    config: dict | None = None,
) -> Logger:
    """A torchrl ``Logger``.

    Args:
        backend: ``"wandb"`` or ``"csv"``.
        exp_name: run name.
        log_dir: where logs go (wandb writes ``<log_dir>/wandb/offline-run-*``).
        project: wandb project.
        online: sync to wandb live (otherwise offline: ``wandb sync`` the folder later).
        run_id: resume this wandb run (after ``--resume``).
        config: hyper-parameters to record.

    Falls back to CSV (with a warning) when wandb cannot start.
    """
    if backend not in ("wandb", "csv"):
        raise ValueError(f"unknown logger backend {backend!r}; valid: ['wandb', 'csv']")
    os.makedirs(log_dir, exist_ok=True)
    if backend == "wandb":
        try:
            from torchrl.record.loggers.wandb import WandbLogger

            kwargs = {"resume": "allow", "id": run_id} if run_id else {}
            logger = WandbLogger(exp_name=exp_name, offline=not online, save_dir=log_dir, project=project,
                                 config=config or {}, **kwargs)
            return logger
        except Exception as err:  # wandb missing, broken, or refused: keep training, log to CSV
            warnings.warn(f"wandb unusable ({type(err).__name__}: {err}); logging to CSV in {log_dir}", stacklevel=2)
    return CSVLogger(exp_name=exp_name, log_dir=log_dir)


class MetricsFile:
    """Appends one JSON line of scalars per iteration to ``path`` (``metrics.jsonl``).

    Kept beside the wandb/CSV logs so learning curves can be plotted without any service
    (``python recipes/plot_curves.py run_dir``).

    Args:
        path: the file (appended to; created with its folder).
        resume_step: the step (env frames) of the checkpoint a resumed run continues from. Rows
            past it were written after that checkpoint by the interrupted process and will be
            written again, so they are dropped (the file is rewritten atomically).
    """

    def __init__(self, path: str | os.PathLike, resume_step: int | None = None) -> None:
        self.path = os.fspath(path)
        os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)
        if resume_step is not None and os.path.isfile(self.path):
            self._drop_after(int(resume_step))

    def _drop_after(self, step: int) -> None:
        import json

        with open(self.path) as f:
            lines = [line for line in f if line.strip()]
        keep = [line for line in lines if json.loads(line).get("step", 0) <= step]
        if len(keep) == len(lines):
            return
        tmp = self.path + ".tmp"
        with open(tmp, "w") as f:
            f.writelines(keep)
        os.replace(tmp, self.path)

    def write(self, step: int, scalars: dict) -> None:
        """Append ``{"step": step, **scalars}`` (non-finite values written as null)."""
        import json
        import math

        row = {"step": int(step)}
        for k, v in scalars.items():
            v = float(v)
            row[k] = v if math.isfinite(v) else None
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")
