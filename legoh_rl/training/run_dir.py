"""A training run's folder belongs to one run.

``checkpoint.dir`` holds ``last.pt``, ``metrics.jsonl`` and ``logs/``. The rules:

* A fresh run (``checkpoint.resume=null``) refuses a folder that holds a checkpoint: continue it
  (``checkpoint.resume=auto``), start over (``checkpoint.overwrite=true``: the old run's files are
  moved into ``overwritten-<time>/`` inside the folder, nothing is deleted), or pick another folder.
  A new stage (``checkpoint.resume=<another run's checkpoint>``) is refused the same way.
* Logs of a run that died before its first checkpoint cannot be continued: a fresh start moves
  them into ``abandoned-<time>/`` and says so.
* A lock (``run.lock``, an advisory ``flock`` the OS drops when the process dies) refuses a
  second live run in the same folder; after a crash the next run takes it over.
* Temporary files of a checkpoint write that was killed (``last.pt.*.tmp``) are removed.

An evaluation's folder (``recipes/evaluate.py``'s ``output_dir``) belongs to one evaluation
(:func:`open_eval_dir`): ``eval.lock`` refuses a second live evaluation there, and a folder that
holds an earlier evaluation's files is refused unless ``overwrite=true``, which moves them into
``overwritten-<time>/`` first.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import time
from pathlib import Path

__all__ = ["RunDirError", "check_run_dir", "RunDirLock", "open_run_dir", "open_eval_dir", "EVAL_FILES"]

#: what a run writes into its folder
RUN_FILES = ("last.pt", "metrics.jsonl", "logs")
#: what ``recipes/evaluate.py`` writes into its ``output_dir`` (glob patterns; ``evaluated_with.json``
#: is written last, so a folder without it holds an evaluation that did not finish)
EVAL_FILES = ("evaluated_with.json", "table*.md", "table*.csv", "episodes.csv", "trajectories.png", "*.mp4", "videos",
              "logs")


class RunDirError(RuntimeError):
    """A run folder that this run may not use as asked (the message says what to do)."""


def _holds_checkpoint(run_dir: Path) -> bool:
    return (run_dir / "last.pt").is_file()


def check_run_dir(run_dir: str | os.PathLike, resume: str | None, overwrite: bool = False) -> None:
    """Refuse to start a run over another run's checkpoint (no side effects).

    Args:
        run_dir: ``checkpoint.dir``.
        resume: ``checkpoint.resume``: ``None``, ``"auto"`` or a checkpoint path.
        overwrite: ``checkpoint.overwrite``: start over, moving the old run aside.

    Raises:
        RunDirError: the folder holds a checkpoint this run would not continue (names it and the
            three ways on).
    """
    run_dir = Path(run_dir)
    last = run_dir / "last.pt"
    if overwrite or resume == "auto" or not last.is_file():
        return
    if resume is not None and Path(resume).resolve() == last.resolve():
        return
    what = "a fresh run" if resume is None else f"a new stage from {resume}"
    raise RunDirError(
        f"{run_dir} holds another run's checkpoint ({last}); {what} would overwrite it. Continue that run "
        "with checkpoint.resume=auto, start over with checkpoint.overwrite=true (its files are moved "
        f"into {run_dir}/overwritten-<time>/), or choose another checkpoint.dir")


class RunDirLock:
    """An exclusive ``flock`` on ``<run_dir>/run.lock`` held while a run trains.

    The kernel releases it when the process exits, however it exits, so a crashed run leaves no
    stale lock. The file records the holder's pid for the error message.

    Args:
        run_dir: the folder.
        name, holder, doing, key: the lock file's name, and the message's words for the holder
            (``"run"``), what it does there (``"is training in"``) and the setting that picks
            another folder (``"checkpoint.dir"``); :func:`open_eval_dir` sets them for evaluations.

    Raises:
        RunDirError: another live process holds the lock (names its pid and the folder).
    """

    def __init__(self, run_dir: str | os.PathLike, name: str = "run.lock", holder: str = "run",
                 doing: str = "is training in", key: str = "checkpoint.dir") -> None:
        self.path = Path(run_dir) / name
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.pread(self._fd, 64, 0).decode(errors="replace").strip() or "unknown"
            os.close(self._fd)
            self._fd = None
            raise RunDirError(f"another {holder} (pid {pid}) {doing} {self.path.parent}: wait for it to "
                              f"finish, stop it, or choose another {key}") from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()}\n".encode(), 0)

    def release(self) -> None:
        """Drop the lock (also done by the OS at exit)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> RunDirLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _present(folder: Path, patterns: tuple[str, ...]) -> list[Path]:
    """The entries of ``folder`` matching any of ``patterns`` (globs), sorted, each once."""
    return sorted({p for pattern in patterns for p in folder.glob(pattern)})


def _move_aside(run_dir: Path, label: str, files: tuple[str, ...] = RUN_FILES) -> Path | None:
    """Move the entries of ``run_dir`` matching ``files`` (its run's files) into
    ``run_dir/<label>-<time>/``; return it (None if none)."""
    present = _present(run_dir, files)
    if not present:
        return None
    dest = run_dir / f"{label}-{time.strftime('%Y%m%d-%H%M%S')}"
    k = 1
    while dest.exists():
        dest = run_dir / f"{label}-{time.strftime('%Y%m%d-%H%M%S')}-{k}"
        k += 1
    dest.mkdir()
    for p in present:
        shutil.move(str(p), dest / p.name)
    return dest


def open_run_dir(run_dir: str | os.PathLike, resume: str | None, overwrite: bool = False) -> RunDirLock:
    """Take ``run_dir`` for this run: check it, lock it, and clear what earlier processes left.

    Call before the run writes anything; release the returned lock when the run ends.

    Args:
        run_dir: ``checkpoint.dir``.
        resume: ``checkpoint.resume`` (``None``, ``"auto"`` or a path).
        overwrite: ``checkpoint.overwrite``.

    Raises:
        RunDirError: see :func:`check_run_dir` and :class:`RunDirLock`.
    """
    run_dir = Path(run_dir)
    check_run_dir(run_dir, resume, overwrite)
    lock = RunDirLock(run_dir)
    try:
        stale = list(run_dir.glob("last.pt.*.tmp"))
        for tmp in stale:  # we hold the lock: no live writer owns them
            tmp.unlink()
        if stale:
            print(f"removed {len(stale)} partial checkpoint file(s) left by a killed run in {run_dir}")
        continues = _holds_checkpoint(run_dir) and (resume == "auto" or (
            resume is not None and Path(resume).resolve() == (run_dir / "last.pt").resolve()))
        if not continues:
            label = "overwritten" if _holds_checkpoint(run_dir) else "abandoned"
            moved = _move_aside(run_dir, label)
            if moved is not None:
                why = ("checkpoint.overwrite=true" if label == "overwritten"
                       else "a run that never wrote a checkpoint cannot be continued")
                print(f"{run_dir}: the earlier run's files moved to {moved} ({why})")
    except BaseException:
        lock.release()
        raise
    return lock


def open_eval_dir(output_dir: str | os.PathLike, overwrite: bool = False) -> RunDirLock:
    """Take ``output_dir`` for one evaluation (``recipes/evaluate.py``); release the returned lock
    when it ends.

    * ``eval.lock`` (a ``flock``, as :class:`RunDirLock`) refuses a second live evaluation into the
      same folder, naming the folder and the running one's pid.
    * A folder that holds files of an earlier evaluation (:data:`EVAL_FILES`: its tables,
      ``episodes.csv``, plot, videos, ``logs/``, ``evaluated_with.json``), finished or not, is
      refused: the two evaluations' files would mix. ``overwrite=true`` moves them into
      ``overwritten-<time>/`` inside the folder first (nothing is deleted).
    * A training run's folder (``last.pt`` or ``run.lock``) is refused whatever ``overwrite`` says:
      its ``logs/`` are the run's.

    Raises:
        RunDirError: any of the refusals above; the message names the folder and what to do.
    """
    output_dir = Path(output_dir)
    training = [name for name in ("last.pt", "run.lock") if (output_dir / name).exists()]
    if training:
        raise RunDirError(f"output_dir={output_dir} is a training run's folder (it holds {training[0]}): an "
                          "evaluation there would mix its files with the run's; choose another output_dir")
    lock = RunDirLock(output_dir, name="eval.lock", holder="evaluation", doing="is writing into", key="output_dir")
    try:
        present = _present(output_dir, EVAL_FILES)
        if present:
            names = [p.name for p in present]
            finished = (output_dir / "evaluated_with.json").is_file()
            what = "an earlier evaluation's results" if finished else "the files of an evaluation that did not finish"
            if not overwrite:
                raise RunDirError(
                    f"output_dir={output_dir} holds {what} ({', '.join(names)}); a new evaluation would mix its "
                    "files with them. Start over with overwrite=true (they are moved into "
                    f"{output_dir}/overwritten-<time>/, nothing is deleted), or choose another output_dir")
            moved = _move_aside(output_dir, "overwritten", EVAL_FILES)
            print(f"{output_dir}: {what} moved to {moved} (overwrite=true)")
    except BaseException:
        lock.release()
        raise
    return lock
