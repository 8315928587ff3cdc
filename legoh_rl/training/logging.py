"""Loggers: torchrl's WandbLogger (offline by default), CSVLogger when wandb is unusable."""

from __future__ import annotations

import os
import warnings

from torchrl.record.loggers import CSVLogger, Logger

__all__ = ["make_logger", "runtime_versions", "MetricsFile", "trim_csv_logs"]


def runtime_versions() -> dict[str, str]:
    """Python and the versions of the packages a run depends on (recorded with its config)."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in ("torch", "torchrl", "tensordict", "mujoco", "legoh-rl"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "absent"
    return out


def make_logger(
    backend: str,
    exp_name: str,
    log_dir: str,
    project: str = "legoh-rl",
    online: bool = False,
    run_id: str | None = None,
    config: dict | None = None,
    group: str | None = None,
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
        group: wandb run group (an experiment's training stages and its evaluations side by side).

    Falls back to CSV (with a warning) when wandb cannot start.
    """
    if backend not in ("wandb", "csv"):
        raise ValueError(f"unknown logger backend {backend!r}; valid: ['wandb', 'csv']")
    os.makedirs(log_dir, exist_ok=True)
    if backend == "wandb":
        try:
            from torchrl.record.loggers.wandb import WandbLogger

            kwargs = {"resume": "allow", "id": run_id} if run_id else {}
            if group:
                kwargs["group"] = group
            # torchrl would write its package list over the config's "env" section (the env
            # settings runs are filtered by); the versions go under "runtime" instead
            logger = WandbLogger(exp_name=exp_name, offline=not online, save_dir=log_dir, project=project,
                                 config={**(config or {}), "runtime": runtime_versions()},
                                 log_env_packages=False, **kwargs)
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
        """Keep the rows up to ``step``; a torn last line (a kill mid-write) is dropped too.

        Raises:
            ValueError: a line other than the last is not JSON (names the file and line).
        """
        import json

        with open(self.path) as f:
            lines = f.readlines()
        keep = []
        for i, line in enumerate(lines):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError as err:
                if i == len(lines) - 1:  # cut short by a kill: the row is written again
                    continue
                raise ValueError(f"{self.path}, line {i + 1}, is not a JSON row ({err}); repair or remove that "
                                 "line, then resume") from None
            if row.get("step", 0) <= step:
                keep.append(line if line.endswith("\n") else line + "\n")
        if keep == lines:
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


def trim_csv_logs(log_dir: str | os.PathLike, step: int) -> int:
    """Drop the rows past ``step`` (and torn lines) from torchrl ``CSVLogger`` files under ``log_dir``.

    A resumed run writes those steps again, so each step stays in each file once. Returns the
    number of rows dropped.
    """
    from pathlib import Path

    dropped = 0
    for path in Path(log_dir).rglob("scalars/**/*.csv"):
        lines = path.read_text().splitlines(keepends=True)
        keep = []
        for line in lines:
            parts = line.rstrip("\n").split(",")
            try:
                ok = line.endswith("\n") and len(parts) == 2 and float(parts[0]) <= step
                float(parts[1])
            except ValueError:
                ok = False
            if ok:
                keep.append(line)
        if len(keep) != len(lines):
            dropped += len(lines) - len(keep)
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text("".join(keep))
            os.replace(tmp, path)
    return dropped
