"""Staged training schedules as data: an experiment's ``stages:`` section, run in order.

A schedule changes settings as a policy learns (first balance at a slow command, then walk, then
harder terrain). In an experiment config it reads::

    stages:
      balance:
        frames: 2_703_360           # run frames (counted from the first stage) at which it ends
        overrides: {env: {cmd_speed: 0.3, reward_overrides: {alive: 10.0}}}
      walk:
        frames: 8_540_160
        overrides: {env: {cmd_speed: 0.5}}
      levels:
        frames: 14_991_360
        keep_curriculum: true       # default; false puts the worlds back on env.levels
        overrides: {ppo: {entropy_coeff: 0.001}}

Stages run in the order of their ``frames``. Each one is the experiment's config with the stage's
``overrides`` merged in (mappings merge key by key, lists and values replace), trained into
``<checkpoint.dir>/stage<k>-<name>/`` until ``frames``: the first from scratch (or
``checkpoint.init``), each later one resuming the previous stage's ``last.pt`` (networks,
optimiser, counters, curriculum, RNG) under its new settings. Running the same command again
skips the finished stages and resumes an interrupted one. After the last stage its policy is
exported to ``<checkpoint.dir>/policy.pt``. An experiment that extends another may drop one of
its stages by setting it to ``null``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from legoh_rl.training.checkpoint import export_policy, load_checkpoint

__all__ = ["Stage", "parse_stages", "stage_dir", "stage_settings", "stage_config", "run_stages", "run_experiment"]

_NAME = re.compile(r"^[A-Za-z0-9_]+$")


@dataclass(frozen=True)
class Stage:
    """One stage of a schedule.

    Attributes:
        name: a short identifier (letters, digits, ``_``); names the stage's folder.
        frames: run frames at which the stage ends (cumulative over the stages).
        overrides: config values that differ from the experiment's (nested mapping).
        keep_curriculum: whether the worlds keep the levels the previous stage's curriculum left.
    """

    name: str
    frames: int
    overrides: dict
    keep_curriculum: bool = True


def parse_stages(raw: Mapping | None) -> list[Stage]:
    """The stages of an experiment's ``stages:`` mapping, ordered by ``frames`` (``[]`` for none).

    Raises:
        ValueError: a bad name, ``frames`` that are not positive integers or not all different,
            ``overrides`` that are not a mapping, or an unknown key in a stage (each names the stage).
    """
    if raw is None:
        return []
    if isinstance(raw, DictConfig):
        raw = OmegaConf.to_container(raw, resolve=True)
    if not isinstance(raw, Mapping):
        raise ValueError(f"stages must be a mapping of stage name -> {{frames, overrides, keep_curriculum}}, got {raw!r}")
    stages = []
    for name, spec in raw.items():
        if spec is None:  # dropped by an experiment that extends another
            continue
        if not isinstance(name, str) or not _NAME.match(name):
            raise ValueError(f"stage name {name!r}: use letters, digits and _ only")
        if not isinstance(spec, Mapping):
            raise ValueError(f"stage {name}: expected a mapping with frames and overrides, got {spec!r}")
        unknown = sorted(set(spec) - {"frames", "overrides", "keep_curriculum"})
        if unknown:
            raise ValueError(f"stage {name}: unknown keys {unknown}; a stage has frames, overrides, keep_curriculum")
        frames = spec.get("frames")
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
            raise ValueError(f"stage {name}: frames must be a positive integer (run frames at its end), got {frames!r}")
        overrides = spec.get("overrides") or {}
        if not isinstance(overrides, Mapping):
            raise ValueError(f"stage {name}: overrides must be a mapping of config values, got {overrides!r}")
        stages.append(Stage(name, frames, dict(overrides), bool(spec.get("keep_curriculum", True))))
    stages.sort(key=lambda s: s.frames)
    ends = [s.frames for s in stages]
    if len(set(ends)) != len(ends):
        raise ValueError(f"stages {[s.name for s in stages]} end at frames {ends}: each must end at a different count")
    return stages


def stage_dir(root: str | Path, index: int, stage: Stage) -> Path:
    """The folder of the ``index``-th stage (0-based) under the experiment's ``checkpoint.dir``."""
    return Path(root) / f"stage{index + 1}-{stage.name}"


def stage_settings(cfg: DictConfig, stage: Stage) -> DictConfig:
    """What a stage trains with: the experiment's config (without ``stages``) with the stage's
    overrides merged in, ``collector.total_frames`` its end and ``stage_name`` its name."""
    out = OmegaConf.merge(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "stages"]), stage.overrides)
    with open_dict(out):
        out.collector.total_frames = stage.frames
        out.stage_name = stage.name
    return out


def stage_config(cfg: DictConfig, stages: list[Stage], index: int) -> DictConfig:
    """The config the ``index``-th stage runs: :func:`stage_settings`, its own folder, and the
    checkpoint it starts from (its own ``last.pt`` when interrupted, else the previous stage's).

    Raises:
        FileNotFoundError: a later stage whose previous stage has no checkpoint yet.
    """
    stage, root = stages[index], cfg.checkpoint.dir
    out = stage_settings(cfg, stage)
    own = stage_dir(root, index, stage) / "last.pt"
    if own.is_file():
        resume = str(own)
    elif index > 0:
        previous = stage_dir(root, index - 1, stages[index - 1]) / "last.pt"
        if not previous.is_file():
            raise FileNotFoundError(f"stage {stage.name} starts from stage {stages[index - 1].name}'s checkpoint, "
                                    f"and {previous} does not exist: run the stages in order")
        resume = str(previous)
    else:
        resume = None
    with open_dict(out):
        out.checkpoint.dir = str(stage_dir(root, index, stage))
        out.checkpoint.resume = resume
        out.checkpoint.keep_curriculum = stage.keep_curriculum
        out.checkpoint.overwrite = False
        if index > 0 and "init" in out.checkpoint:  # (oracle_ppo's key)
            out.checkpoint.init = None  # later stages resume; only the first may start from a policy
    return out


def _finished(cfg: DictConfig) -> bool:
    """Whether a stage's own checkpoint already covers its frames (less than one batch left)."""
    own = Path(cfg.checkpoint.dir) / "last.pt"
    if not own.is_file():
        return False
    batch = int(cfg.env.num_envs) * int(cfg.collector.steps_per_env)
    return int(load_checkpoint(own)["frames"]) > int(cfg.collector.total_frames) - batch


def run_stages(cfg: DictConfig, train: Callable[[DictConfig], dict]) -> dict:
    """Train every unfinished stage of ``cfg.stages`` with ``train`` (a recipe's train function).

    Returns:
        the last trained stage's summary, with ``stage`` (its name), and ``policy`` (the
        exported policy) once every stage is done; an interrupted stage's summary (with
        ``interrupted``) ends the schedule early.

    Raises:
        ValueError: ``checkpoint.resume`` names a file (stages resume on their own: use ``auto``).
    """
    stages = parse_stages(cfg.get("stages"))
    resume = cfg.checkpoint.get("resume")
    if resume not in (None, "auto"):
        raise ValueError(f"checkpoint.resume={resume!r}: a staged experiment resumes its stages on its own; "
                         "run the same command again (checkpoint.resume=auto or nothing)")
    summary: dict = {}
    for index, stage in enumerate(stages):
        stage_cfg = stage_config(cfg, stages, index)
        if _finished(stage_cfg):
            print(f"stage {index + 1}/{len(stages)} {stage.name}: done ({stage_cfg.checkpoint.dir}/last.pt)")
            continue
        print(f"stage {index + 1}/{len(stages)} {stage.name}: to {stage.frames} frames in {stage_cfg.checkpoint.dir}")
        summary = {**train(stage_cfg), "stage": stage.name}
        if summary.get("interrupted"):
            return summary
    last = stage_dir(cfg.checkpoint.dir, len(stages) - 1, stages[-1]) / "last.pt"
    summary["policy"] = str(export_policy(last, Path(cfg.checkpoint.dir) / "policy.pt"))
    summary.setdefault("checkpoint", str(last))
    return summary


def run_experiment(cfg: DictConfig, train: Callable[[DictConfig], dict], recipe: str) -> dict:
    """Run ``cfg`` with a recipe's ``train``: its stages when it has any, else one run.

    Args:
        recipe: the recipe's name (``"oracle_ppo"``, ``"unified"``); an experiment that names
            another recipe in its ``recipe`` key is refused.

    Raises:
        ValueError: the experiment is meant for another recipe.
    """
    meant = cfg.get("recipe")
    if meant is not None and meant != recipe:
        raise ValueError(f"recipe={meant!r}: experiment {cfg.get('experiment_name')!r} is for recipes/{meant}.py, "
                         f"not recipes/{recipe}.py")
    if parse_stages(cfg.get("stages")):
        return run_stages(cfg, train)
    return train(cfg)
