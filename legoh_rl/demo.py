"""`make demo`: the project's main job on embedded defaults (CPU, wandb offline), a few minutes.

1. a short oracle PPO training (H1, easy RandomMix trails) through ``recipes/oracle_ppo.py``,
   logged to an offline wandb run;
2. the benchmark (``recipes/evaluate.py``) on easy trails: the metrics table (markdown + CSV),
   the torso-trajectory plot and a video of four robots. It evaluates the committed trained
   oracle (``checkpoints/oracle_h1.pt``) when the repository has one, else the checkpoint the
   short training just wrote;
3. a list of where every artefact is.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("WANDB_MODE", "offline")

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
COMMITTED_ORACLE = ROOT / "checkpoints" / "oracle_h1.pt"
OUT = Path(os.environ.get("LEGOH_DEMO_OUT", "outputs/demo"))


def _compose(name: str, overrides: list[str]):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def main(argv: list[str] | None = None) -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m legoh_rl.demo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Artefacts go to $LEGOH_DEMO_OUT (default outputs/demo).")
    parser.parse_args(argv)
    sys.path.insert(0, str(RECIPES))
    import oracle_ppo

    from legoh_rl.training import eval_run

    start = time.perf_counter()
    print("legoh-rl demo: (1) short oracle PPO training on easy trails, (2) the hiking benchmark\n")
    train_dir = OUT / "oracle_h1"
    summary = oracle_ppo.train(_compose("oracle_ppo", [
        "env.robot=h1", "env.num_envs=64", "env.categories=[randommix]", "env.variants=2",
        "collector.steps_per_env=24", "collector.total_frames=30720", f"checkpoint.dir={train_dir}",
        "checkpoint.every=5", "logger.exp_name=demo_oracle_h1",
        "checkpoint.overwrite=true",  # a demo starts over each time (the last run is moved aside)
    ]))
    trained = Path(summary["checkpoint"])
    print(f"\ntrained {summary['iteration']} PPO iterations ({summary['frames']} env steps): "
          f"mean reward/step {summary.get('reward/total', float('nan')):.3f}")
    policy = COMMITTED_ORACLE if COMMITTED_ORACLE.is_file() else trained
    which = "the committed trained oracle" if policy == COMMITTED_ORACLE else "the checkpoint just trained"
    print(f"\nevaluating {which}: {policy}")
    eval_dir = OUT / "eval"
    result = eval_run.evaluate(_compose("evaluate", [
        f"checkpoint={policy}", "categories=[randommix,ditch]", "levels=[0,1]", "robots_per_cell=4",
        f"output_dir={eval_dir}", "video_seconds=6", "logger.exp_name=demo_eval",
        "overwrite=true",  # the last demo's evaluation is moved aside, as its training is
    ]))
    wandb_runs = sorted(str(p) for p in OUT.rglob("offline-run-*") if p.is_dir())
    print(f"\ndemo finished in {time.perf_counter() - start:.0f} s. Artefacts:")
    rows = [
        ("training checkpoint", str(trained)),
        ("evaluated policy", str(policy)),
        ("metrics table", result["table"]),
        ("metrics per level", result["levels"]),
        ("metrics CSV", result["csv"]),
        ("trajectory plot", result["plot"]),
        ("video", result["video"] or "(skipped: no OpenGL context for MuJoCo rendering)"),
    ] + [("wandb offline run", run) for run in wandb_runs]
    for name, path in rows:
        print(f"  {name:20} {path}")
    if wandb_runs:
        print("\nsync the wandb runs later with:  wandb sync " + " ".join(wandb_runs))


if __name__ == "__main__":
    main()
