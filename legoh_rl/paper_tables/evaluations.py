"""Our figures for the rows: the protocol every checkpoint is evaluated on (:class:`Settings`), one
evaluation per checkpoint file (:func:`evaluate_checkpoint`, :func:`legoh_rl.training.eval_run.evaluate`
on a config composed from ``evaluate.yaml``) with a cache of earlier evaluations keyed by their
record (:func:`find_evaluation`, :func:`archive_evaluation`: an evaluation of the same checkpoint
file on the same protocol is read back, not run again), and every row's result
(:func:`run_rows`)."""

from __future__ import annotations

import csv
import hashlib
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from legoh_rl.envs.trails import CATEGORIES, NUM_LEVELS
from legoh_rl.paper_tables.paper import Value
from legoh_rl.paper_tables.rows import ROWS, CheckpointInfo, across_seeds, read_info, resolve_row
from legoh_rl.training import eval_run

__all__ = ["Settings", "find_evaluation", "read_table_csv", "archive_evaluation",
           "evaluate_checkpoint", "RowResult", "run_rows"]


@dataclass(frozen=True)
class Settings:
    """The protocol every checkpoint is evaluated on (``recipes/evaluate.py``'s config keys).

    Attributes:
        trail_seeds: one trail grid per seed (distinct, at least one); mean ± std is over them.
        robots_per_cell, runs: per (category, level) cell and per trail grid (``protocol="cpu"``;
            ``"paper"`` sets 20 and 5).
        variants: trail variants per cell; categories, levels: the cells.
        protocol: ``"cpu"`` or ``"paper"``.
        device, num_threads: where the policy runs, physics threads (None: the default).
        video: render ``evaluate.py``'s video of each checkpoint; logger: ``"csv"`` or ``"wandb"``.
        domain_rand: evaluate under the training's randomisation (``evaluate.py domain_rand=true``)
            instead of on the nominal robot.
    """

    trail_seeds: tuple[int, ...]
    robots_per_cell: int = 2
    runs: int = 1
    variants: int = 2
    categories: tuple[str, ...] = CATEGORIES
    levels: tuple[int, ...] = tuple(range(NUM_LEVELS))
    protocol: str = "cpu"
    device: str = "auto"
    num_threads: int | None = None
    video: bool = False
    logger: str = "csv"
    domain_rand: bool = False

    def __post_init__(self) -> None:
        """Refuse a bad protocol before any evaluation, with ``evaluate.py``'s own checks (its
        protocol and trail seeds, :class:`~legoh_rl.training.evaluation.EvalProtocol`'s cells)."""
        keys = ("protocol", "categories", "levels", "robots_per_cell", "runs", "trail_seeds")
        cfg = OmegaConf.create({**{k: v for k, v in self.overrides(Path("-"), Path("-")).items() if k in keys},
                                "seed": 0})
        eval_run.protocol_of(cfg)
        eval_run.trail_seeds_of(cfg)
        if int(self.variants) < 1:
            raise ValueError(f"variants must be >= 1, got {self.variants}")
        if self.num_threads is not None and self.num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {self.num_threads}")
        if self.logger not in ("csv", "wandb"):
            raise ValueError(f"unknown logger {self.logger!r}; valid: ['csv', 'wandb']")

    def overrides(self, checkpoint: Path, output_dir: Path) -> dict:
        """The ``evaluate.yaml`` keys for one checkpoint."""
        return {"checkpoint": str(checkpoint), "protocol": self.protocol, "robots_per_cell": self.robots_per_cell,
                "runs": self.runs, "variants": self.variants, "categories": list(self.categories),
                "levels": list(self.levels), "trail_seeds": list(self.trail_seeds), "device": self.device,
                "num_threads": self.num_threads, "output_dir": str(output_dir), "video": self.video,
                "domain_rand": self.domain_rand,
                # evaluated again only where no evaluation there matches: the earlier one moves into
                # overwritten-<time>/ (where find_evaluation still finds it), not mixed with the new
                "overwrite": True,
                "logger": {"backend": self.logger, "exp_name": f"paper_tables_{output_dir.name}"}}

    def describe(self) -> str:
        """One line: the cells, robots, runs and trail grids."""
        paper = self.protocol == "paper"
        robots = eval_run.PAPER_ROBOTS_PER_CELL if paper else self.robots_per_cell
        runs = eval_run.PAPER_RUNS if paper else self.runs
        episodes = robots * len(self.categories) * len(self.levels) * runs * len(self.trail_seeds)
        return (f"protocol {self.protocol}: {robots} robot(s) per cell on {self.variants} trail variant(s), "
                f"categories {list(self.categories)} x levels {list(self.levels)}, {runs} run(s) on each of "
                f"{len(self.trail_seeds)} trail grid(s) (seeds {list(self.trail_seeds)}): {episodes} episodes per "
                "checkpoint, one 30 s episode each"
                + (", under the training's domain randomisation" if self.domain_rand else ""))


def find_evaluation(record: dict, folders: Sequence[Path]) -> Path | None:
    """A folder holding an evaluation made with ``record`` (its record file,
    :data:`~legoh_rl.training.eval_run.RECORD_NAME`, equal to it,
    beside its ``table.csv``): each of ``folders`` or one of their subfolders; None if none."""
    for folder in folders:
        for stamp in [Path(folder) / eval_run.RECORD_NAME, *sorted(Path(folder).glob(f"*/{eval_run.RECORD_NAME}"))]:
            if stamp.is_file() and (stamp.parent / "table.csv").is_file() and json.loads(stamp.read_text()) == record:
                return stamp.parent
    return None


def read_table_csv(path: Path) -> dict[str, dict[str, Value]]:
    """An evaluation's ``table.csv`` (``category,metric,mean,std``) as its aggregate."""
    rows: dict[str, dict[str, Value]] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            rows.setdefault(r["category"], {})[r["metric"]] = (float(r["mean"]), float(r["std"]))
    return rows


def archive_evaluation(found: Path, record: dict, archive: Path, name: str) -> Path:
    """Keep an evaluation's figures and what they depend on (its record,
    :data:`~legoh_rl.training.eval_run.RECORD_NAME`, and
    ``table.csv``, a few kB) in ``archive/<name>-<record digest>/``, a folder that can be committed
    so a fresh checkout refills the tables without evaluating again; returns that folder. The digest
    (12 hex digits of the record's SHA-256) keeps the same checkpoint's evaluations on other
    protocols apart."""
    digest = hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:12]
    kept = Path(archive) / f"{name}-{digest}"
    if kept.resolve() != Path(found).resolve():
        kept.mkdir(parents=True, exist_ok=True)
        (kept / "table.csv").write_bytes((Path(found) / "table.csv").read_bytes())
        (kept / eval_run.RECORD_NAME).write_text(json.dumps(record, indent=1) + "\n")  # last: only a complete copy matches
    return kept


def evaluate_checkpoint(path: Path, settings: Settings, output_dir: Path, reuse: bool = True,
                        reuse_from: Sequence[Path] = (), archive: Path | None = None) -> dict[str, dict[str, Value]]:
    """:func:`legoh_rl.training.eval_run.evaluate` on one checkpoint, its config composed from
    ``evaluate.yaml`` with ``settings``.

    Each evaluation leaves :data:`~legoh_rl.training.eval_run.RECORD_NAME` beside its ``table.csv``
    (``eval_run.evaluation_record``); with ``reuse`` a folder whose record matches (the same
    checkpoint file and protocol), ``output_dir`` or one found in ``reuse_from`` (an
    ``evaluate.py`` run's output folder, or a folder of them), is read back instead of evaluated
    again, so the tables can be rewritten as rows are added without re-running the others
    (``--fresh``: evaluate everything). With ``archive`` the evaluation is also looked up there and
    kept there (:func:`archive_evaluation`).

    Returns:
        the aggregate: {group: {metric: (mean, std)}}, groups the categories and ``"overall"``.
    """
    with initialize_config_dir(config_dir=str(eval_run.CONFIG_DIR), version_base=None):
        cfg = compose(config_name="evaluate")
    cfg = OmegaConf.merge(cfg, settings.overrides(path, output_dir))
    record = eval_run.evaluation_record(cfg)
    stamp = output_dir / eval_run.RECORD_NAME
    searched = [output_dir, *([archive] if archive is not None else []), *reuse_from]
    found = find_evaluation(record, searched) if reuse else None
    if found is not None:
        print(f"{path}: reusing the evaluation in {found} (same checkpoint and protocol)", flush=True)
        rows = read_table_csv(found / "table.csv")
    else:
        rows = eval_run.evaluate(cfg)["rows"]  # moves an earlier evaluation there aside, its record too
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(json.dumps(record, indent=1) + "\n")
        found = output_dir
    if archive is not None:
        archive_evaluation(found, record, archive, output_dir.name)
    return rows


@dataclass
class RowResult:
    """Our figures for one row.

    Attributes:
        key: the row; status: ``"evaluated"``, ``"not trained"`` or ``"failed"``.
        path: the checkpoint evaluated (the first, with several seeds), or the one that would
            hold the row.
        note: why not trained (what other candidates hold) or why the evaluation failed.
        rows: the aggregate ({group: {metric: (mean, std)}}) when evaluated: one checkpoint's
            mean ± std over trail grids, or with several seeds the mean ± std over the seeds
            (:func:`~legoh_rl.paper_tables.rows.across_seeds`).
        paths: every checkpoint of the row (its training seeds).
        per_seed: each checkpoint's own aggregate, in the order of ``paths``.
        frames: each checkpoint's env steps of training, in the order of ``paths`` (None: not
            recorded).
    """

    key: str
    status: str
    path: Path
    note: str = ""
    rows: dict[str, dict[str, Value]] | None = field(default=None, repr=False)
    paths: tuple[Path, ...] = ()
    per_seed: list[dict] | None = field(default=None, repr=False)
    frames: tuple[int | None, ...] = ()


def run_rows(keys: Sequence[str], root: Path, settings: Settings, out: Path,
             evaluate_fn: Callable[[Path, Settings, Path], dict] = evaluate_checkpoint,
             read: Callable[[Path], CheckpointInfo] = read_info) -> dict[str, RowResult]:
    """Resolve and evaluate rows, each checkpoint once.

    Args:
        keys: rows of :data:`~legoh_rl.paper_tables.rows.ROWS`.
        root: the checkpoints folder.
        settings: the protocol.
        out: the output folder (each evaluation writes under ``out/evals/<checkpoint>``).
        evaluate_fn: (path, settings, output_dir) -> aggregate; ``read``: path -> info (for tests).

    Returns:
        {key: :class:`RowResult`}. An evaluation that raises is recorded as ``"failed"`` (the
        error in ``note``) and the other rows go on.
    """
    cache: dict[Path, tuple[str, object]] = {}
    results = {}
    for key in dict.fromkeys(keys):
        res = resolve_row(ROWS[key], root, read)
        if not res.found:
            results[key] = RowResult(key, "not trained", res.path, res.note)
            print(f"{key}: not trained ({res.path}{'; ' + res.note if res.note else ''})", flush=True)
            continue
        for path in res.paths:
            where = path.resolve()
            if where not in cache:
                print(f"\n=== {key}: evaluating {path} ===", flush=True)
                name = str(path.relative_to(root).with_suffix("")).replace("/", "_")
                try:
                    cache[where] = ("evaluated", evaluate_fn(path, settings, out / "evals" / name))
                except Exception as err:  # one bad checkpoint must not lose the others' hours of evaluation
                    cache[where] = ("failed", f"{type(err).__name__}: {err}")
                    print(f"{key}: evaluation of {path} failed: {cache[where][1]}", file=sys.stderr, flush=True)
        outcomes = [cache[p.resolve()] for p in res.paths]
        failed = [str(value) if len(res.paths) == 1 else f"{p}: {value}"
                  for p, (status, value) in zip(res.paths, outcomes, strict=True) if status == "failed"]
        if failed:  # a row is not reported on fewer seeds than it has
            results[key] = RowResult(key, "failed", res.path, note="; ".join(failed), paths=res.paths,
                                     frames=res.frames)
            continue
        per_seed = [value for _, value in outcomes]
        rows = per_seed[0] if len(per_seed) == 1 else across_seeds(per_seed)
        results[key] = RowResult(key, "evaluated", res.path, rows=rows, paths=res.paths, per_seed=per_seed,
                                 frames=res.frames)
    return results
