"""The humanoid hiking benchmark: a checkpoint on the categories x levels protocol.

Prints the six metrics as mean +- std per category and overall (markdown and CSV) and per
level (``table_levels.md``), saves a plot
of torso trajectories over the trails coloured by time and a short video of a few robots, and
logs all of it to wandb (offline by default).

    python recipes/evaluate.py checkpoint=outputs/oracle_h1/last.pt
    python recipes/evaluate.py checkpoint=outputs/oracle_h1/last.pt protocol=paper
    python recipes/evaluate.py checkpoint=zero robot=g1       # PD-hold baseline, no policy
    python recipes/evaluate.py checkpoint=... trail_seeds=[0,1,2]   # three trail sets pooled
    python recipes/evaluate.py checkpoint=deploy/oracle_h1.onnx     # ONNX export, onnxruntime
    python recipes/evaluate.py checkpoint=... video_per_category=true   # also videos/<category>.mp4
    python recipes/evaluate.py checkpoint=... device=cpu            # a GPU-trained checkpoint on the CPU
    python recipes/evaluate.py checkpoint=... domain_rand=true      # under the training's randomisation

A ``.onnx`` checkpoint is an export of ``recipes/export_policy.py --format onnx``: ``OUT.onnx`` is an
oracle's graph, or names a student's pair ``OUT.perception.onnx`` + ``OUT.locomotion.onnx``; it runs
with onnxruntime (``pip install 'legoh-rl[deploy]'``) in the same loop (docs/deploy.md).

Beside its tables an evaluation leaves ``evaluated_with.json``: the checkpoint file's SHA-256 and
every setting its figures depend on (``legoh_rl.training.eval_run.evaluation_record``), so
``recipes/paper_tables.py`` can take it up instead of evaluating the same checkpoint on the same
protocol again.

An ``output_dir`` belongs to one evaluation at a time (``legoh_rl/training/run_dir.py``,
``open_eval_dir``): a second evaluation into a folder where one is running is refused with the
running one's pid, and a folder that already holds an evaluation's files is refused unless
``overwrite=true``, which moves them into ``overwritten-<time>/`` inside it first (nothing is
deleted). Each trail grid's env is released before the next is built, so the peak memory does
not grow with ``trail_seeds`` (``benchmarks/eval_memory.py``).

``domain_rand=true`` runs the benchmark under the training's domain randomisation (friction,
base mass and CoM, motor strength, pushes every 8 s, one step of action delay): a robustness test
beside the nominal benchmark, which is the default and what the paper's tables compare.
``domain_rand=[push]`` (any of ``friction base_mass base_com motor_strength push action_delay``)
draws only the terms named, to tell which perturbation costs a policy most.

``trail_seeds`` repeats the protocol on trail grids generated with each seed (new trails, same
categories, levels and variants). A deterministic policy on an unrandomised trail has a single
outcome, so a few variants are a small sample; each trail set counts as one run of the tables'
mean +- std.

The run itself is :func:`legoh_rl.training.eval_run.evaluate` (every setting checked first by its
``validate``, each refusal naming the key); this script is its command line.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: off-screen rendering

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

from legoh_rl.training.eval_run import evaluate  # noqa: E402


@hydra.main(config_path="config", config_name="evaluate", version_base=None)
def main(cfg: DictConfig) -> None:
    evaluate(cfg)


if __name__ == "__main__":
    main()
