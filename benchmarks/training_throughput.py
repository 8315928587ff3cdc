"""Env steps/s of training against the env alone, in one run (H1).

    python benchmarks/training_throughput.py [--oracle-iters 8] [--student-iters 6] [--skip-student]
        [--skip-oracle] [--oracle-update-threads 1 2] [--oracle-settings "" "kl_measure=loss_forward"]
        [--repeats 2] [--students student_h1_trails student_h1] [--student-settings "" "collector.overlap=true ..."]

Each training rate is printed as env steps/s and as a ratio to its env alone (same worlds, mode
and threads):

* (a) the env alone under random actions: oracle mode with the oracle recipe's worlds (256, all
  physics threads, the foot scan), and the student env of each ``--students`` experiment (its worlds,
  categories, levels and ``env.num_threads``, depth on); measured before and after the training
  runs, and averaged, so drifting machine load hits both sides;
* (b) oracle training, ``recipes/oracle_ppo.py experiment=oracle_h1_foot_scan`` started afresh
  (``checkpoint.init=null``, no feedforward anneal; 256 worlds on
  the whole benchmark, [256, 128, 64] MLPs, 5 epochs x 4 minibatches), once per
  ``--oracle-update-threads`` count (torch threads of the PPO update; collection keeps 1) and
  per ``--oracle-settings`` entry (extra overrides, space-separated; ``""``: the experiment as
  it is; an entry that sets ``update_threads`` itself keeps its own), the whole set
  ``--repeats`` times in turn (A B A B: drifting load hits every setting alike); a row per count and setting, its rate over all its runs;
* (c) student training, ``recipes/unified.py experiment=<name>`` for each ``--students``
  experiment, with the experiment's own teacher: the DAgger phase as it runs once
  the teacher's share has decayed (the student acts, the teacher labels: ``dagger_decay_iters=1``),
  then the PPO + L_im + L_hie phase (``dagger_iters=1``, HLM on). The experiments' own thread
  counts (``torch_threads``, ``env.num_threads``: 2 for the committed ones) are kept.

Training rates count collection and update time per iteration from the run's own
``metrics.jsonl`` (``train/collect_s`` + ``train/update_s``), leaving out the first iteration
(building, first reset). Runs go to a temporary folder. Note what else runs on the machine
with the figures (BENCHMARKS.md).
"""

from __future__ import annotations

import legoh_rl.openmp  # noqa: F401  (first, as in the recipes: OpenMP's wait policy is read when torch loads)

# isort: split
import argparse
import sys
import tempfile
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training.builders import policy_env_kwargs
from legoh_rl.training.checkpoint import load_checkpoint
from legoh_rl.training.config_store import env_config
from legoh_rl.training.run_log import read_metrics, training_hours

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402


def compose_cfg(name: str, overrides: list[str]):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def env_rate(cfg: HikingEnvConfig, steps: int) -> float:
    """Env steps/s of ``cfg``'s env under random actions over ``steps`` control steps (after a
    warm-up of 50 steps)."""
    env = HikingEnv(cfg)
    try:
        env.rollout(50, break_when_any_done=False)
        start = time.perf_counter()
        env.rollout(steps, break_when_any_done=False)
        return cfg.num_envs * steps / (time.perf_counter() - start)
    finally:
        env.close()


def timed_frames(run_dir: Path) -> tuple[int, float]:
    """(env steps, seconds) of a run's metrics, its first iteration left out: each iteration's
    ``train/iteration_s`` (from one batch in hand to the next) where the run logged it, else its
    collection + update seconds. With ``collector.overlap`` the two overlap, so only the former
    counts them right."""
    rows = read_metrics(run_dir / "metrics.jsonl")
    hours = training_hours(rows)
    return rows[-1]["step"] - rows[0]["step"], (hours[-1] - hours[0]) * 3600.0


def training_rate(run_dir: Path) -> tuple[float, int]:
    """(env steps/s, iterations timed) from a run's metrics, its first iteration left out."""
    frames, seconds = timed_frames(run_dir)
    rows = (run_dir / "metrics.jsonl").read_text().splitlines()
    return frames / seconds, len(rows) - 1


def student_env(name: str):
    """``(config, env config)`` of experiment ``name``: its env section in student mode (depth on),
    with its teacher's gait clock, as ``recipes/unified.py`` builds it."""
    cfg = compose_cfg("unified", [f"experiment={name}"])
    return cfg, env_config(cfg.env, "student", **policy_env_kwargs(load_checkpoint(ROOT / cfg.teacher)["meta"]))


def alone_rates(args) -> dict[str, float]:
    """Env steps/s of the env alone: ``oracle`` (256 worlds, all threads) and each student
    experiment's env (torch's threads set to its ``torch_threads``)."""
    rates = {}
    if not args.skip_oracle:
        torch.set_num_threads(1)  # the oracle recipe's collection (torch_threads=1; physics on all cores)
        rates["oracle"] = env_rate(HikingEnvConfig(num_envs=256, levels=(0, 1, 2, 3, 4), variants=8, foot_scan=True),
                                   args.env_steps)
    for name in [] if args.skip_student else args.students:
        cfg, env_cfg = student_env(name)
        torch.set_num_threads(int(cfg.torch_threads))
        rates[name] = env_rate(env_cfg, args.env_steps)
    return rates


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--oracle-iters", type=int, default=8, help="oracle iterations (6,144 frames each)")
    p.add_argument("--student-iters", type=int, default=6, help="student iterations per phase")
    p.add_argument("--env-steps", type=int, default=200, help="timed control steps of the env alone")
    p.add_argument("--oracle-update-threads", type=int, nargs="+", default=[1],
                   help="update_threads of the oracle runs (one row per count)")
    p.add_argument("--oracle-settings", nargs="+", default=[""],
                   help='extra overrides of the oracle runs, one row each ("" = none; "a=1 b=2": two overrides)')
    p.add_argument("--repeats", type=int, default=1,
                   help="oracle runs per count and setting, alternated (A B A B)")
    p.add_argument("--students", nargs="+", default=["student_h1_trails", "student_h1"],
                   help="unified experiments to measure (one pair of rows each)")
    p.add_argument("--student-settings", nargs="+", default=[""],
                   help='extra overrides of the student runs, one pair of rows each ("" = none)')
    p.add_argument("--skip-student", action="store_true")
    p.add_argument("--skip-oracle", action="store_true")
    args = p.parse_args()
    if any(k < 1 for k in args.oracle_update_threads):
        p.error(f"--oracle-update-threads must be positive, got {args.oracle_update_threads}")
    if args.repeats < 1:
        p.error(f"--repeats must be positive, got {args.repeats}")
    before = alone_rates(args)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        timed: dict[tuple[int, str], list[tuple[int, float]]] = {}  # (threads, setting): (frames, seconds) a run
        variants = [] if args.skip_oracle else [(k, v) for k in args.oracle_update_threads for v in args.oracle_settings]
        for rep in range(args.repeats):
            for n, (k, setting) in enumerate(variants):
                run = Path(tmp) / f"oracle{k}-{n}-{rep}"
                frames = 256 * 24 * (args.oracle_iters + 1)
                oracle_ppo.train(compose_cfg("oracle_ppo", ["experiment=oracle_h1_foot_scan", f"checkpoint.dir={run}",
                                                            "checkpoint.init=null", "checkpoint.init_widen=false",
                                                            "feedforward_anneal=null", f"collector.total_frames={frames}",
                                                            *([] if "update_threads=" in setting else [f"update_threads={k}"]),
                                                            "logger.backend=csv", *setting.split()]))
                timed.setdefault((k, setting), []).append(timed_frames(run))
        for (k, setting), runs in timed.items():
            frames, seconds = map(sum, zip(*runs, strict=True))
            each = " / ".join(f"{f / s:,.0f}" for f, s in runs)
            threads = "" if "update_threads=" in setting else f", update on {k} thread(s)"
            rows.append((f"(b) oracle training, 256 worlds, whole benchmark{threads}"
                         + (f", `{setting}`" if setting else "") + (f" (runs: {each})" if len(runs) > 1 else ""),
                         "oracle", frames / seconds, len(runs) * args.oracle_iters))
        for name in [] if args.skip_student else args.students:
            cfg, env_cfg = student_env(name)
            frames = env_cfg.num_envs * int(cfg.collector.steps_per_env) * (args.student_iters + 1)
            for n, setting in enumerate(args.student_settings):
                for phase, extra in (("DAgger", ["dagger_decay_iters=1"]),
                                     ("PPO + L_im + L_hie", ["dagger_iters=1", "dagger_decay_iters=1", "hlm.enabled=true",
                                                             "hlm.warmup_iters=1"])):
                    run = Path(tmp) / f"{name}-{phase.split()[0].lower()}-{n}"
                    torch.set_num_threads(int(cfg.torch_threads))
                    unified.train(compose_cfg("unified", [f"experiment={name}", *extra, f"teacher={ROOT / cfg.teacher}",
                                                          f"checkpoint.dir={run}", f"collector.total_frames={frames}",
                                                          "checkpoint.snapshot_every=0", "logger.backend=csv",
                                                          *setting.split()]))
                    rows.append((f"(c) student training, `{name}`, {phase}" + (f", `{setting}`" if setting else ""),
                                 name, *training_rate(run)))
    after = alone_rates(args)
    alone = {k: (before[k] + after[k]) / 2 for k in before}
    print("\n| measurement | env steps/s | ratio to the env alone |")
    print("|---|---:|---:|")
    if "oracle" in alone:
        print(f"| (a) env alone, oracle mode, 256 worlds (before / after: {before['oracle']:,.0f} / "
              f"{after['oracle']:,.0f}) | {alone['oracle']:,.0f} | 1.00 |")
    for name in [] if args.skip_student else args.students:
        _, env_cfg = student_env(name)
        print(f"| (a) env alone, `{name}`'s student env ({env_cfg.num_envs} worlds, {env_cfg.num_threads} thread(s); "
              f"before / after: {before[name]:,.0f} / {after[name]:,.0f}) | {alone[name]:,.0f} | 1.00 |")
    for name, mode, rate, iters in rows:
        print(f"| {name} ({iters} iterations) | {rate:,.0f} | {rate / alone[mode]:.2f} |")


if __name__ == "__main__":
    main()
