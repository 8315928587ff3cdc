"""Batch-1 latency of the deployment graphs, onnxruntime against torch, on the control budgets.

    python benchmarks/deploy_latency.py
    python benchmarks/deploy_latency.py --runs 500 --threads 1 --oracle checkpoints/oracle_h1.pt \
        --student checkpoints/student_h1.pt

Exports the oracle and the student (``legoh_rl.training.onnx_export``, as
``recipes/export_policy.py --format onnx`` does) to a temporary folder and times every graph at
batch 1 on random inputs of the right shapes: the onnxruntime session (CPU, ``--threads``
intra-op threads) and the same network in torch eager (``torch.set_num_threads(--threads)``,
``inference_mode``), alternating one call of each so both see the same machine load. Prints
the median and 95th percentile per graph against its budget: 20 ms for the 50 Hz control graphs
(oracle, student locomotion), 100 ms for the 10 Hz perception graph (TC-ViT + GRU), and the
student's tick step (perception then locomotion in one thread) against 20 ms.

Latencies on a shared machine are pessimistic: other processes compete for the cores.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from legoh_rl.training.checkpoint import load_checkpoint
from legoh_rl.training.onnx_export import (
    export_onnx,
    feature_shapes,
    make_session,
    oracle_graph,
    sample_inputs,
    student_graphs,
)

CONTROL_BUDGET_MS = 20.0  # 50 Hz
PERCEPTION_BUDGET_MS = 100.0  # 10 Hz


def timer(graph, path: Path, inputs: tuple[torch.Tensor, ...], threads: int):
    """``(onnxruntime call, torch call)``, each running the graph once on ``inputs``."""
    sess = make_session(path, threads)
    feeds = {i.name: x.numpy() for i, x in zip(sess.get_inputs(), inputs, strict=True)}

    def ort_call():
        sess.run(None, feeds)

    def torch_call():
        with torch.inference_mode():
            graph(*inputs)

    return ort_call, torch_call


def measure(calls: dict, runs: int, warmup: int) -> dict[str, list[float]]:
    """Milliseconds of every call in ``calls`` ({name: fn}), ``runs`` times, interleaved."""
    for _ in range(warmup):
        for fn in calls.values():
            fn()
    times: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(runs):
        for k, fn in calls.items():
            t0 = time.perf_counter()
            fn()
            times[k].append((time.perf_counter() - t0) * 1e3)
    return times


def summary(ms: list[float]) -> tuple[float, float]:
    """``(median, p95)`` in ms."""
    return statistics.median(ms), float(np.percentile(ms, 95))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--oracle", type=Path, default=Path("checkpoints/oracle_h1.pt"))
    parser.add_argument("--student", type=Path, default=Path("checkpoints/student_h1.pt"))
    parser.add_argument("--runs", type=int, default=300, help="timed calls of each graph")
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime and torch threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    import onnxruntime

    print(f"torch {torch.__version__}, onnxruntime {onnxruntime.__version__}, {args.threads} thread(s), "
          f"batch 1, {args.runs} runs\n")
    with tempfile.TemporaryDirectory() as tmp:
        calls: dict = {}
        budgets = {}
        ost = load_checkpoint(args.oracle)
        paths = export_onnx(args.oracle, Path(tmp) / "oracle.onnx")
        g = oracle_graph(ost)
        o, t = timer(g, paths["oracle"], sample_inputs(g, feature_shapes(ost["meta"], None), 1), args.threads)
        calls.update({("oracle", "onnxruntime"): o, ("oracle", "torch"): t})
        budgets["oracle"] = ("50 Hz", CONTROL_BUDGET_MS)

        sst = load_checkpoint(args.student)
        paths = export_onnx(args.student, Path(tmp) / "student.onnx")
        perc, loco, pcfg = student_graphs(sst)
        shapes = feature_shapes(sst["meta"], pcfg)
        for name, graph, rate, budget in (("perception", perc, "10 Hz", PERCEPTION_BUDGET_MS),
                                          ("locomotion", loco, "50 Hz", CONTROL_BUDGET_MS)):
            o, t = timer(graph, paths[name], sample_inputs(graph, shapes, 1), args.threads)
            calls.update({(name, "onnxruntime"): o, (name, "torch"): t})
            budgets[name] = (rate, budget)
        times = measure(calls, args.runs, args.warmup)
    for backend in ("onnxruntime", "torch"):  # the tick step: both graphs, one after the other
        times[("tick step", backend)] = [p + q for p, q in zip(times[("perception", backend)],
                                                                 times[("locomotion", backend)], strict=True)]
    budgets["tick step"] = ("50 Hz", CONTROL_BUDGET_MS)
    print("| graph | rate | budget (ms) | onnxruntime median / p95 (ms) | torch median / p95 (ms) | within budget |")
    print("|---|---|---:|---:|---:|---|")
    for name, (rate, budget) in budgets.items():
        om, op = summary(times[(name, "onnxruntime")])
        tm, tp = summary(times[(name, "torch")])
        ok = "yes" if max(op, tp) <= budget else ("onnxruntime only" if op <= budget else "no")
        label = "student tick step (perception + locomotion)" if name == "tick step" else name
        print(f"| {label} | {rate} | {budget:.0f} | {om:.3f} / {op:.3f} | {tm:.3f} / {tp:.3f} | {ok} |", flush=True)


if __name__ == "__main__":
    main()
