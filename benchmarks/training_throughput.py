"""Env steps/s of training against the env alone, in one run (H1).

    python benchmarks/training_throughput.py [--oracle-iters 8] [--student-iters 6] [--skip-student]
        [--skip-oracle] [--oracle-update-threads 1 2] [--student-threads 1 2]

Four measurements, each printed as env steps/s and as a ratio to the env alone at the same
worlds count and threads:

* (a) the env alone under random actions: oracle mode with the oracle recipe's worlds (256, all
  physics threads), and student mode (64x64 depth) with the committed student's (32 worlds,
  one physics thread); measured before and after the training runs, and averaged, so drifting
  machine load hits both sides;
* (b) oracle training, ``recipes/oracle_ppo.py experiment=oracle_h1_footholds`` (256 worlds on
  the whole benchmark, [256, 128, 64] MLPs, 5 epochs x 4 minibatches), once per
  ``--oracle-update-threads`` count (torch threads of the PPO update; collection keeps 1);
* (c) student training, ``recipes/unified.py`` with the committed student's settings (32 worlds,
  RandomMix levels 0-1, ``cpu`` TC-ViT, one thread, the locomotion replay window) and
  ``checkpoints/oracle_h1.pt`` as the teacher: the DAgger phase, then the PPO + L_im + L_hie
  phase (HLM on). ``--student-threads 1 2`` repeats (c), and the student env alone, with
  ``torch_threads`` and ``env.num_threads`` at each count (one run alone on the machine can use
  both cores; the committed students ran two side by side, one core each).

Training rates count collection and update time per iteration from the run's own
``metrics.jsonl`` (``train/collect_s`` + ``train/update_s``), leaving out the first iteration
(building, first reset). Runs go to a temporary folder. Note what else runs on the machine
with the figures (BENCHMARKS.md).
"""

from __future__ import annotations

import legoh_rl.openmp  # noqa: F401  (first, as in the recipes: OpenMP's wait policy is read when torch loads)

# isort: split
import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir

from legoh_rl.envs import HikingEnv, HikingEnvConfig

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

#: the committed student's settings (experiment student_h1_randommix, replay stage)
STUDENT = ["env.num_envs=32", "env.categories=[randommix]", "env.levels=[0,1]", "env.variants=4",
           "env.curriculum=false", "env.cmd_speed=0.5",
           "env.reward_overrides={alive: 4.0, termination: -100.0}", "student.perception=tcvit",
           "student.preset=cpu", "dagger_epochs=4",
           "dagger_replay={capacity: 100000, batch_size: 2048, steps: 8}", "logger.backend=csv"]


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


def training_rate(run_dir: Path) -> tuple[float, int]:
    """(env steps/s, iterations timed) from a run's metrics, its first iteration left out."""
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    timed = rows[1:]
    seconds = sum(r["train/collect_s"] + r["train/update_s"] for r in timed)
    return (timed[-1]["step"] - rows[0]["step"]) / seconds, len(timed)


def student_env_cfg(threads: int) -> HikingEnvConfig:
    """The committed student's env (student mode, RandomMix levels 0-1) with ``threads`` physics threads."""
    return HikingEnvConfig(num_envs=32, mode="student", categories=("randommix",), levels=(0, 1), variants=4,
                           num_threads=threads)


def alone_rates(args) -> dict[str, float]:
    """Env steps/s of the env alone: ``oracle`` (256 worlds, all threads) and ``student<k>`` per
    thread count (torch's threads set to the same count)."""
    rates = {}
    if not args.skip_oracle:
        torch.set_num_threads(1)  # the oracle recipe's collection (torch_threads=1; physics on all cores)
        rates["oracle"] = env_rate(HikingEnvConfig(num_envs=256, levels=(0, 1, 2, 3, 4), variants=8), args.env_steps)
    if not args.skip_student:
        for k in args.student_threads:
            torch.set_num_threads(k)
            rates[f"student{k}"] = env_rate(student_env_cfg(k), args.env_steps)
    return rates


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--oracle-iters", type=int, default=8, help="oracle iterations (6,144 frames each)")
    p.add_argument("--student-iters", type=int, default=6, help="student iterations per phase (768 frames each)")
    p.add_argument("--env-steps", type=int, default=200, help="timed control steps of the env alone")
    p.add_argument("--oracle-update-threads", type=int, nargs="+", default=[1],
                   help="update_threads of the oracle runs (one row per count)")
    p.add_argument("--student-threads", type=int, nargs="+", default=[1],
                   help="torch and physics threads of the student runs (one set of rows per count)")
    p.add_argument("--skip-student", action="store_true")
    p.add_argument("--skip-oracle", action="store_true")
    args = p.parse_args()
    for name in ("student_threads", "oracle_update_threads"):
        if any(k < 1 for k in getattr(args, name)):
            p.error(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    teacher = ROOT / "checkpoints" / "oracle_h1.pt"
    before = alone_rates(args)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in [] if args.skip_oracle else args.oracle_update_threads:
            run = Path(tmp) / f"oracle{k}"
            frames = 256 * 24 * (args.oracle_iters + 1)
            oracle_ppo.train(compose_cfg("oracle_ppo", ["experiment=oracle_h1_footholds", f"checkpoint.dir={run}",
                                                        "checkpoint.init=null", f"collector.total_frames={frames}",
                                                        f"update_threads={k}", "logger.backend=csv"]))
            rows.append((f"(b) oracle training, 256 worlds, whole benchmark, update on {k} thread(s)", "oracle",
                         *training_rate(run)))
        for k in [] if args.skip_student else args.student_threads:
            frames = 32 * 24 * (args.student_iters + 1)
            threads = [f"torch_threads={k}", f"env.num_threads={k}"]
            for phase, extra in (("DAgger", ["dagger_iters=1000", "hlm.enabled=false"]),
                                 ("PPO + L_im + L_hie", ["dagger_iters=1", "hlm.enabled=true", "hlm.warmup_iters=1"])):
                run = Path(tmp) / f"{phase.split()[0].lower()}{k}"
                torch.set_num_threads(k)
                unified.train(compose_cfg("unified", STUDENT + threads + extra + [
                    f"teacher={teacher}", f"checkpoint.dir={run}", f"collector.total_frames={frames}"]))
                rows.append((f"(c) student training, {phase}, {k} thread(s)", f"student{k}", *training_rate(run)))
    after = alone_rates(args)
    alone = {k: (before[k] + after[k]) / 2 for k in before}
    print("\n| measurement | env steps/s | ratio to the env alone |")
    print("|---|---:|---:|")
    if "oracle" in alone:
        print(f"| (a) env alone, oracle mode, 256 worlds (before / after: {before['oracle']:,.0f} / "
              f"{after['oracle']:,.0f}) | {alone['oracle']:,.0f} | 1.00 |")
    for k in [] if args.skip_student else args.student_threads:
        key = f"student{k}"
        print(f"| (a) env alone, student mode, 32 worlds, {k} thread(s) (before / after: {before[key]:,.0f} / "
              f"{after[key]:,.0f}) | {alone[key]:,.0f} | 1.00 |")
    for name, mode, rate, iters in rows:
        print(f"| {name} ({iters} iterations) | {rate:,.0f} | {rate / alone[mode]:.2f} |")


if __name__ == "__main__":
    main()
