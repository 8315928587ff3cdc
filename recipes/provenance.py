"""How was this checkpoint made? Its experiment, lineage and resolved config, in one command.

    python recipes/provenance.py checkpoints/student_h1.pt            # lineage and the command
    python recipes/provenance.py checkpoints/student_h1.pt --config   # ... and the resolved config

For a checkpoint (a run's ``last.pt`` or a slim export) it prints:

* what it is: kind, robot, iteration and env steps, its SHA-256;
* the experiment and stage that trained it (the meta block), the chain of experiment files it
  extends (``defaults:``) and the command that trains it (``recipes/<recipe>.py experiment=...``);
* whether that experiment, composed today, still gives the settings the checkpoint recorded
  (the keys that differ, if any); where today's says ``feedforward_anneal: inherit``, the gait
  feedforward schedule the checkpoint followed against the one inherit reads from its
  ``checkpoint.init`` (:func:`schedule_differences`);
* where it started from: its teacher (a student's), ``checkpoint.init`` (an oracle's), the run it
  branched from (``checkpoint.branch``), each followed in turn while the file is at hand;
* with ``--config``, the resolved config it trained with, as YAML, in today's layout of the
  settings (:func:`~legoh_rl.training.config_store.upgrade_recorded_config`: a run recorded before
  the env section held every field reads with the fields it left out at their defaults).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from legoh_rl.training.checkpoint import file_digest, load_checkpoint, recorded_checkpoint
from legoh_rl.training.config_store import register_configs, upgrade_recorded_config
from legoh_rl.training.schedules import INHERIT, inherited_schedule, recorded_schedule

ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = ROOT / "recipes" / "config"
EXPERIMENTS = CONFIG_DIR / "experiment"
#: keys of the recorded config that say where and how a run was launched, not what it trained
LAUNCH_KEYS = ("checkpoint", "logger", "device", "stage_name", "stages", "torch_threads", "update_threads")


def experiment_chain(name: str) -> list[str]:
    """``[name, parent, grandparent, ...]``: the experiment files ``name`` extends through its
    ``defaults:`` list (a file that is missing ends the chain)."""
    chain = []
    while name and (EXPERIMENTS / f"{name}.yaml").is_file() and name not in chain:
        chain.append(name)
        parents = [d for d in (OmegaConf.load(EXPERIMENTS / f"{name}.yaml").get("defaults") or [])
                   if isinstance(d, str) and d != "_self_"]
        name = parents[0] if parents else None
    return chain


def differences(recorded, today, prefix: str = "") -> tuple[list[str], list[str]]:
    """``(changed, added)`` dotted keys between two plain configs, launch settings left out:
    ``changed`` those whose values differ (or that the code no longer has), ``added`` those the
    code gained since the checkpoint was written (their defaults are what a newer run takes)."""
    changed, added = [], []
    for key in sorted(set(recorded) | set(today)):
        if not prefix and key in LAUNCH_KEYS:
            continue
        if key not in recorded:
            added.append(f"{prefix}{key}")
            continue
        a, b = recorded[key], today.get(key, "<no longer a setting>")
        if isinstance(a, dict) and isinstance(b, dict):
            more = differences(a, b, f"{prefix}{key}.")
            changed += more[0]
            added += more[1]
        elif a != b:
            changed.append(f"{prefix}{key}: recorded {a!r}, today {b!r}")
    return changed, added


def without_schedule(config: dict) -> dict:
    """``config`` without the two settings ``feedforward_anneal: inherit`` replaces by the schedule
    it reads (``env.gait_feedforward`` and ``feedforward_anneal``)."""
    out = {k: v for k, v in config.items() if k != "feedforward_anneal"}
    if isinstance(out.get("env"), dict):
        out["env"] = {k: v for k, v in out["env"].items() if k != "gait_feedforward"}
    return out


def schedule_differences(state: dict, path: Path, config: dict) -> list[str]:
    """For an experiment that today says ``feedforward_anneal: inherit``: ``[]`` when checkpoint
    ``state`` (at ``path``, recorded ``config``) followed the gait feedforward schedule inherit
    gives from its ``checkpoint.init``, else one line saying what differs or why it cannot be told."""
    try:
        have = recorded_schedule(state, path)
    except ValueError as err:
        return [f"feedforward_anneal: today inherit; {err}"]
    init = (config.get("checkpoint") or {}).get("init")
    if not init:
        return [f"feedforward_anneal: recorded {have.describe()}, today inherit (no checkpoint.init recorded)"]
    source = Path(init) if Path(init).is_absolute() else ROOT / init
    if not source.is_file():
        return [f"feedforward_anneal: recorded {have.describe()}, today inherit from {init} (not on this machine)"]
    try:
        want = inherited_schedule(load_checkpoint(source), init)
    except ValueError as err:
        return [f"feedforward_anneal: recorded {have.describe()}, today inherit; {err}"]
    if want.anneal == have.anneal and math.isclose(want.gain, have.gain, rel_tol=1e-12, abs_tol=1e-15):
        return []
    return [f"feedforward_anneal: recorded {have.describe()}, today inherit from {init}: {want.describe()}"]


def composed(recipe: str, experiment: str, stage: str | None) -> dict:
    """The config ``recipes/<recipe>.py experiment=<experiment>`` composes today (the stage's
    settings merged in when the checkpoint names one), resolved to plain containers."""
    from legoh_rl.training.stages import parse_stages, stage_settings

    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg = compose(config_name=recipe, overrides=[f"experiment={experiment}"])
    if stage:
        match = [s for s in parse_stages(cfg.get("stages")) if s.name == stage]
        if match:
            cfg = stage_settings(cfg, match[0])
    return OmegaConf.to_container(cfg, resolve=True)


def describe(path: Path, depth: int = 0, seen: set | None = None) -> list[str]:
    """Lines describing checkpoint ``path`` and, indented, the checkpoints it started from."""
    seen = set() if seen is None else seen
    pad = "  " * depth
    if not path.is_file():
        return [f"{pad}{path}: not on this machine (the lineage stops here)"]
    key = path.resolve()
    if key in seen:
        return [f"{pad}{path}: (above)"]
    seen.add(key)
    state = load_checkpoint(path)
    meta = state.get("meta", {})
    config = upgrade_recorded_config(state["config"]) if state.get("config") else {}  # in today's layout
    if config.get("teacher"):  # the teacher's file today: found by its digest, or through a rename
        config["teacher"] = recorded_checkpoint(config["teacher"], state.get("teacher_sha256")
                                                or meta.get("teacher_sha256"), ROOT)
    shown = path.resolve().relative_to(ROOT) if path.resolve().is_relative_to(ROOT) else path
    lines = [f"{pad}{shown}",
             f"{pad}  kind {meta.get('kind')}, robot {meta.get('robot')}, iteration {state.get('iteration')}, "
             f"{state.get('frames')} env steps, sha256 {file_digest(path)[:16]}"]
    experiment, stage = meta.get("experiment"), meta.get("stage")
    recipe = config.get("recipe") or ("unified" if meta.get("kind") == "student" else "oracle_ppo")
    if experiment:
        chain = experiment_chain(experiment)
        where = " <- ".join(f"{n}.yaml" for n in chain) if chain else f"{experiment}.yaml (no longer in {EXPERIMENTS})"
        lines.append(f"{pad}  experiment {experiment}" + (f", stage {stage}" if stage else "") + f": {where}")
        lines.append(f"{pad}  trained by: python recipes/{recipe}.py experiment={experiment} checkpoint.resume=auto")
        if chain and config:
            today = composed(recipe, experiment, stage)
            recorded, schedule = config, []
            if today.get("feedforward_anneal") == INHERIT:  # compared as the schedule it reads instead
                schedule = schedule_differences(state, path, config)
                recorded, today = without_schedule(config), without_schedule(today)
            diff, added = differences(recorded, today)
            diff += schedule
            lines.append(f"{pad}  the experiment today gives the recorded settings" if not diff else
                         f"{pad}  the experiment today differs from the recorded settings in {len(diff)} key(s):")
            lines += [f"{pad}    {d}" for d in diff]
            if added:
                lines.append(f"{pad}  settings added to the code since (not recorded): {', '.join(added)}")
    else:
        lines.append(f"{pad}  no named experiment in its meta block (a run from the plain recipe config)")
    sources = []
    if config.get("teacher"):
        sources.append(("teacher", config["teacher"]))
    start = config.get("checkpoint") or {}
    if start.get("init"):
        sources.append(("checkpoint.init", start["init"]))
    branch = meta.get("branched_from") or {}
    if branch.get("checkpoint"):
        sources.append((f"branched at iteration {branch.get('iteration')} from", branch["checkpoint"]))
    for label, source in sources:
        lines.append(f"{pad}  {label}:")
        lines += describe(ROOT / source if not Path(source).is_absolute() else Path(source), depth + 2, seen)
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path, help="a run's last.pt or a slim policy file")
    parser.add_argument("--config", action="store_true", help="also print the resolved config it trained with")
    args = parser.parse_args(argv)
    if not args.checkpoint.is_file():
        parser.error(f"no checkpoint at {args.checkpoint}")
    print("\n".join(describe(args.checkpoint)))
    if args.config:
        config = load_checkpoint(args.checkpoint).get("config")
        config = upgrade_recorded_config(config) if config else None  # today's keys, as a command line sets them
        print("\nresolved config:\n" + (OmegaConf.to_yaml(OmegaConf.create(config)) if config else
                                         "  (none recorded: a checkpoint written before runs kept their config)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
