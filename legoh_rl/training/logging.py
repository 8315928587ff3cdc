"""Loggers: torchrl's WandbLogger (offline by default), CSVLogger when wandb is unusable."""

from __future__ import annotations

import os
import warnings

from torchrl.record.loggers import CSVLogger, Logger

__all__ = ["make_logger"]


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
