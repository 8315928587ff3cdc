"""One run of the humanoid hiking benchmark, as ``recipes/evaluate.py`` and ``recipes/paper_tables.py``
run it: the checks of an ``evaluate.yaml`` config (:func:`validate`), the record of what an
evaluation's figures depend on (:func:`evaluation_record`, left as :data:`RECORD_NAME` beside its
tables), and the run itself (:func:`evaluate`): every trail grid of ``trail_seeds`` in turn, its
tables (``table.md``, ``table_levels.md``, ``table_cells.md``, ``table.csv``), ``episodes.csv``,
the trajectory plot, the videos and the logged scalars, in an output folder held for this
evaluation alone (:func:`~legoh_rl.training.run_dir.open_eval_dir`).

The protocol's building blocks (the cells, the rollout, the aggregates) are in
:mod:`legoh_rl.training.evaluation`; this module puts them together for one config.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import torch
from omegaconf import DictConfig, ListConfig, OmegaConf

from legoh_rl.envs.config import PHYSICS
from legoh_rl.envs.randomization import DOMAIN_RAND_TERMS, DomainRandConfig
from legoh_rl.envs.robots import ROBOTS
from legoh_rl.envs.trails import ALL_CATEGORIES
from legoh_rl.training.checkpoint import file_digest, load_checkpoint
from legoh_rl.training.config_checks import (
    Choice,
    Flag,
    Integer,
    ListOf,
    Name,
    check_known_keys,
    check_settings,
    recipe_keys,
)
from legoh_rl.training.device import resolve_device
from legoh_rl.training.evaluation import (
    EvalProtocol,
    aggregate,
    category_worlds,
    cell_table,
    eval_scalars,
    long_table,
    markdown_table,
    plot_trajectories,
    release_memory,
    render_videos,
    run_protocol,
    write_csv,
    write_episodes,
)
from legoh_rl.training.logging import make_logger
from legoh_rl.training.policies import load_policy
from legoh_rl.training.run_dir import open_eval_dir

__all__ = [
    "CONFIG_DIR", "PAPER_ROBOTS_PER_CELL", "PAPER_RUNS", "RECORD_NAME", "SETTINGS", "number_of", "numbers_of",
    "protocol_of", "trail_seeds_of", "domain_rand_of", "validate", "evaluation_record", "evaluate", "eval_videos",
    "checkpoint_experiment",
]

#: the recipes' hydra configs; ``evaluate.yaml`` there lists every key an evaluation config has
CONFIG_DIR = Path(__file__).resolve().parents[2] / "recipes" / "config"

PAPER_ROBOTS_PER_CELL = 20  # 20 x 25 cells = 500 ~ the paper's 512 robots
PAPER_RUNS = 5


def _as_number(value, kind: type):
    """``value`` as ``kind`` (``int`` or ``float``), or None where ``int()``/``float()`` would refuse
    it or silently change it: text that is not a number, ``true``/``false``, null, a list, and (for
    ``int``) a number with a fractional part."""
    if isinstance(value, bool) or value is None or isinstance(value, DictConfig | ListConfig | dict | list | tuple):
        return None
    try:
        number = float(value) if kind is float or isinstance(value, float) else int(value)
    except (TypeError, ValueError, OverflowError):
        return None
    if kind is int and isinstance(number, float):
        return int(number) if number.is_integer() else None
    return number


def number_of(key: str, value, kind: type = int):
    """``value`` (of config key ``key``) as an ``int`` or a ``float`` (``kind``).

    Raises:
        ValueError: ``value`` is not one (:func:`_as_number`); the message names ``key`` and
            ``value``: ``seed must be an integer, got 'abc'``.
    """
    number = _as_number(value, kind)
    if number is None:
        raise ValueError(f"{key} must be {'an integer' if kind is int else 'a number'}, got {value!r}")
    return number


def numbers_of(key: str, values, kind: type = int) -> list:
    """``values`` (a list under config key ``key``) as a list of ``kind`` (:func:`number_of`).

    Raises:
        ValueError: not a list, or an entry that is not a ``kind``; the message names ``key``,
            the list and the entry: ``trail_seeds must be a list of integers, got ['abc']: 'abc'
            is not an integer``.
    """
    what = "an integer" if kind is int else "a number"
    plural = "integers" if kind is int else "numbers"
    if not isinstance(values, ListConfig | list | tuple):
        raise ValueError(f"{key} must be a list of {plural}, got {values!r}")
    items = list(values)
    numbers = [_as_number(v, kind) for v in items]
    for value, number in zip(items, numbers, strict=True):
        if number is None:
            raise ValueError(f"{key} must be a list of {plural}, got {items!r}: {value!r} is not {what}")
    return numbers


def protocol_of(cfg: DictConfig) -> EvalProtocol:
    """The :class:`~legoh_rl.training.evaluation.EvalProtocol` of ``cfg``: its cells, and
    ``robots_per_cell`` and ``runs`` as given (``protocol=cpu``) or the paper's (``protocol=paper``).

    Raises:
        ValueError: an unknown protocol, or a cell setting that is not a valid number (names it).
    """
    if cfg.protocol not in ("cpu", "paper"):
        raise ValueError(f"unknown protocol {cfg.protocol!r}; valid: ['cpu', 'paper']")
    paper = cfg.protocol == "paper"
    return EvalProtocol(
        categories=tuple(cfg.categories), levels=tuple(numbers_of("levels", cfg.levels)),
        robots_per_cell=PAPER_ROBOTS_PER_CELL if paper else number_of("robots_per_cell", cfg.robots_per_cell),
        runs=PAPER_RUNS if paper else number_of("runs", cfg.runs), seed=number_of("seed", cfg.seed),
    )


def trail_seeds_of(cfg: DictConfig) -> list[int]:
    """The trail-grid seeds to evaluate on: ``cfg.trail_seeds`` or ``[cfg.seed]``."""
    seeds = cfg.get("trail_seeds")
    if seeds is None:
        return [number_of("seed", cfg.seed)]
    seeds = numbers_of("trail_seeds", seeds)
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"trail_seeds must be a non-empty list of distinct seeds, got {seeds}")
    if min(seeds) < 0:
        raise ValueError(f"trail_seeds must be seeds >= 0, got {seeds}")
    return seeds


#: ``evaluate.yaml``'s settings by kind (``legoh_rl/training/config_checks.py``) but for the numbers
#: and lists that :func:`number_of` and :func:`numbers_of` read (they take "3" for 3, as quoting on
#: a command line may give them), ``protocol`` and ``domain_rand``, which have their own checks
SETTINGS = {
    "checkpoint": Name(),
    "robot": Choice(tuple(ROBOTS), what="robot"),
    "categories": ListOf(Choice(ALL_CATEGORIES, what="trail category")),
    "num_threads": Integer(1, nullable=True),
    "physics": Choice(PHYSICS),
    "device": Name(nullable=True),  # which devices: resolve_device
    "output_dir": Name(),
    "overwrite": Flag(),
    "video": Flag(),
    "video_per_category": Flag(),
    "logger.backend": Choice(("wandb", "csv")),
    "logger.online": Flag(),
    "logger.project": Name(),
    "logger.exp_name": Name(),
    "logger.group": Name(nullable=True),
}


def validate(cfg: DictConfig) -> None:
    """Check every setting before any work, each refusal naming the key and the value: no key
    that ``evaluate.yaml`` does not have, :data:`SETTINGS` of their kind, ``variants`` >= 1,
    ``seed`` >= 0 and ``video_seconds`` a number (positive, unless ``video=false``); then the
    protocol (:func:`protocol_of`), :func:`trail_seeds_of` and :func:`domain_rand_of`.

    Raises:
        ValueError: the first bad setting.
    """
    if cfg.get("checkpoint") is None:
        raise ValueError("checkpoint is required: a .pt file from a recipe, a .onnx export, or 'zero' for the "
                         "PD-hold baseline")
    check_known_keys(cfg, recipe_keys(CONFIG_DIR / "evaluate.yaml"), name="evaluate's config")
    check_settings(cfg, SETTINGS)
    if number_of("variants", cfg.variants) < 1:
        raise ValueError(f"variants must be >= 1 (trail variants per cell), got {cfg.variants!r}")
    if number_of("seed", cfg.seed) < 0:
        raise ValueError(f"seed must be an integer >= 0, got {cfg.seed!r}")
    seconds = number_of("video_seconds", cfg.video_seconds, float)
    if cfg.video and not seconds > 0.0:
        raise ValueError(f"video_seconds must be positive (or video=false for no video), got {cfg.video_seconds}")
    protocol_of(cfg)
    trail_seeds_of(cfg)
    domain_rand_of(cfg)


#: ``evaluate.yaml`` keys that do not change an evaluation's figures (where it runs, what it logs)
NOT_IN_RECORD = ("checkpoint", "output_dir", "overwrite", "video", "video_per_category", "logger", "device",
                 "num_threads")
#: keys added to ``evaluate.yaml`` after records were first written, with the value that gives the
#: evaluation made before the key existed: recorded only when set otherwise, so older records still
#: describe the evaluations they were written for
RECORDED_WHEN_SET = {"domain_rand": False}
#: the file an evaluation leaves beside its tables: :func:`evaluation_record`
RECORD_NAME = "evaluated_with.json"


def evaluation_record(cfg: DictConfig) -> dict:
    """What an evaluation's figures depend on: the checkpoint's SHA-256 (its name for ``zero``)
    and the config but for :data:`NOT_IN_RECORD` (and :data:`RECORDED_WHEN_SET`'s keys at their
    old value)."""
    config = OmegaConf.to_container(cfg, resolve=True)
    path = Path(str(cfg.checkpoint))
    return {"checkpoint_sha256": file_digest(path) if path.is_file() else str(cfg.checkpoint),
            "config": {k: v for k, v in config.items()
                       if k not in NOT_IN_RECORD and not (k in RECORDED_WHEN_SET and v == RECORDED_WHEN_SET[k])}}


def domain_rand_of(cfg: DictConfig) -> bool | tuple[str, ...]:
    """``cfg.domain_rand`` checked: true, false, or a non-empty list of
    :data:`~legoh_rl.envs.randomization.DOMAIN_RAND_TERMS` (returned as a tuple); ValueError
    naming the bad value otherwise."""
    value = cfg.get("domain_rand", False)
    if isinstance(value, bool):
        return value
    if not isinstance(value, ListConfig | list | tuple) or not value:
        raise ValueError(f"domain_rand must be true, false or a non-empty list of terms {list(DOMAIN_RAND_TERMS)}, "
                         f"got {value!r}")
    terms = tuple(str(t) for t in value)
    try:
        DomainRandConfig().only(terms)  # names an unknown term
    except ValueError as err:
        raise ValueError(f"domain_rand: {err}") from None
    if len(set(terms)) != len(terms):
        raise ValueError(f"domain_rand terms must be distinct, got {list(terms)}")
    return terms


def evaluate(cfg: DictConfig) -> dict:
    """Run the benchmark described by ``cfg`` (every setting checked first: :func:`validate`) in
    its ``output_dir``, taken for this evaluation alone (``open_eval_dir``); returns the aggregate
    and the artefact paths."""
    validate(cfg)
    protocol = protocol_of(cfg)
    seeds = trail_seeds_of(cfg)
    variants = number_of("variants", cfg.variants)
    domain_rand = domain_rand_of(cfg)
    device = resolve_device(cfg.get("device"))
    cfg = OmegaConf.merge(cfg, {"device": str(device)})  # the logged config records the device it ran on
    out_dir = Path(cfg.output_dir)
    with open_eval_dir(out_dir, overwrite=bool(cfg.get("overwrite", False))):  # this evaluation's alone
        return _evaluate(cfg, protocol, seeds, variants, domain_rand, device, out_dir)


def _evaluate(cfg: DictConfig, protocol: EvalProtocol, seeds: list[int], variants: int,
              domain_rand: bool | tuple[str, ...], device: torch.device, out_dir: Path) -> dict:
    """:func:`evaluate`'s work on its checked settings, in the output folder it holds."""
    torch.set_num_threads(1)
    record = evaluation_record(cfg)
    (out_dir / RECORD_NAME).unlink(missing_ok=True)  # a stale record must not outlive the tables it described
    episodes = []
    for i, seed in enumerate(seeds):  # trail set i: runs i * runs .. (i + 1) * runs - 1
        print(f"trail set {i + 1}/{len(seeds)} (seed {seed}): {protocol.num_worlds} robots x {protocol.runs} run(s)",
              flush=True)
        env, policy, kind = load_policy(cfg.checkpoint, protocol, robot=cfg.robot, variants=variants,
                                        seed=seed, num_threads=cfg.num_threads, device=device,
                                        physics=cfg.get("physics", "mujoco"), domain_rand=domain_rand)
        part = run_protocol(env, policy, replace(protocol, seed=seed), progress=True)
        episodes += [{**e, "run": i * protocol.runs + e["run"], "trail_seed": seed} for e in part.episodes]
        if i == 0:  # the plot and the video show the first trail set, drawn while its env lives
            result = part
            plot = plot_trajectories(env, result, out_dir / "trajectories.png")
            video, category_videos = eval_videos(env, policy, protocol, cfg, out_dir) if cfg.video else (None, {})
        env.close()  # each grid's env gone before the next is built: memory does not grow with the grids
        del env, policy, part
        release_memory()
    result.episodes = episodes
    rows = aggregate(result.episodes)
    level_rows = aggregate(result.episodes, by="level")
    table = markdown_table(rows)
    (out_dir / "table.md").write_text(table + "\n")
    level_table = markdown_table(level_rows)
    (out_dir / "table_levels.md").write_text(level_table + "\n")
    csv_path = write_csv(rows, out_dir / "table.csv")
    cells = cell_table(result.episodes)
    (out_dir / "table_cells.md").write_text(cells + "\n")
    write_episodes(result.episodes, out_dir / "episodes.csv")
    dr_note = ("" if not domain_rand else ", with domain randomisation" if domain_rand is True
               else f", with domain randomisation of {', '.join(domain_rand)} only")
    print(f"\n{kind} policy, {len(result.episodes)} episodes ({protocol.robots_per_cell} robots x "
          f"{len(protocol.categories)} categories x {len(protocol.levels)} levels x {protocol.runs} runs "
          f"x {len(seeds)} trail sets, seeds {seeds}{dr_note})\n")
    print(table)
    print("\nby level:\n" + level_table)
    print("\nsuccess per category and level:\n" + cells)
    group = cfg.logger.get("group") or checkpoint_experiment(cfg.checkpoint)
    logger = make_logger(cfg.logger.backend, cfg.logger.exp_name, str(out_dir / "logs"), cfg.logger.project,
                         cfg.logger.online, config=OmegaConf.to_container(cfg, resolve=True), group=group)
    level_scalars = {k: v for k, v in eval_scalars(level_rows).items() if "/overall/" not in k}
    logger.log_metrics({**eval_scalars(rows), **level_scalars}, step=0)
    _log_media(logger, rows, level_rows, plot, video, category_videos)
    (out_dir / RECORD_NAME).write_text(json.dumps(record, indent=1) + "\n")
    artefacts = {"table": str(out_dir / "table.md"), "levels": str(out_dir / "table_levels.md"), "csv": str(csv_path), "plot": str(plot),
                 "video": str(video) if video else None}
    print("\nartefacts:\n" + "\n".join(f"  {k:6} {v}" for k, v in artefacts.items() if v))
    for category, path in category_videos.items():
        print(f"  video of {category}: {path}")
    return {"rows": rows, "episodes": result.episodes, **artefacts,
            "category_videos": {c: str(p) for c, p in category_videos.items()}}


def eval_videos(env, policy, protocol: EvalProtocol, cfg: DictConfig, out_dir: Path) -> tuple[Path | None, dict]:
    """The evaluation's videos, drawn in one rollout (:func:`render_videos`): ``robots.mp4``, the
    first four robots, and with ``video_per_category=true`` one clip per category,
    ``videos/<category>.mp4``, its robots one per level (:func:`category_worlds`).

    Returns:
        (robots.mp4 or None, {category: clip}); (None, {}) when this machine cannot render.
    """
    main = out_dir / "robots.mp4"
    clips = {main: list(range(min(4, protocol.num_worlds)))}
    per_category = {}
    if cfg.get("video_per_category", False):
        per_category = {c: out_dir / "videos" / f"{c}.mp4" for c in protocol.categories}
        clips.update({path: category_worlds(protocol, c) for c, path in per_category.items()})
    written = render_videos(env, policy, clips, seconds=number_of("video_seconds", cfg.video_seconds, float))
    if written is None:
        return None, {}
    return written[main], per_category


def checkpoint_experiment(checkpoint) -> str | None:
    """The experiment named in a ``.pt`` checkpoint's meta block (None for others): the wandb
    group that puts an evaluation beside its training runs."""
    if not str(checkpoint).endswith(".pt"):
        return None
    return load_checkpoint(checkpoint).get("meta", {}).get("experiment")


def _log_media(logger, rows: dict, level_rows: dict, plot: Path, video: Path | None,
               category_videos: dict | None = None) -> None:
    """The tables (numeric columns: by, group, metric, mean, std), the trajectory plot and the
    videos (``eval/video``, ``eval/video_<category>``), in one wandb call (nothing for the CSV
    logger, which has the scalars)."""
    exp = getattr(logger, "experiment", None)
    if exp is None or not hasattr(exp, "log"):
        return
    import wandb

    columns, data = long_table(rows, "category")
    data += long_table(level_rows, "level")[1]
    media = {"eval/table": wandb.Table(columns=columns, data=data), "eval/trajectories": wandb.Image(str(plot))}
    if video is not None:
        media["eval/video"] = wandb.Video(str(video), format="mp4")
    for category, path in (category_videos or {}).items():
        media[f"eval/video_{category}"] = wandb.Video(str(path), format="mp4")
    exp.log(media)
    exp.finish()
