"""Peak memory of ``recipes/evaluate.py`` against the number of trail grids (``trail_seeds``).

    python benchmarks/eval_memory.py                                   # student_h1, 1 and 3 grids
    python benchmarks/eval_memory.py --grids 1 3 --robots-per-cell 4 --variants 4
    python benchmarks/eval_memory.py --checkpoint zero --categories randommix --levels 0

Each evaluation runs in a fresh Python process (so one's peak cannot hide another's), with
``trail_seeds=[0]``, ``[0,1]``, ``[0,1,2]``, ... for the grid counts asked, no video and the CSV
logger, into a temporary ``output_dir``. Prints one markdown row per grid count: the process's
peak resident memory (``VmHWM`` from ``/proc/self/status``, the same as ``ru_maxrss``), its
resident memory at the end, the wall time and the peak's ratio to the first row's. An evaluation
whose memory does not grow with the grids reads a ratio near 1.00 on every row.

``--child`` runs one evaluation in this process and prints its figures as one JSON line (what the
parent reads, and what ``tests/test_eval_memory.py`` uses).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _status_kib(field: str) -> int:
    """A ``/proc/self/status`` field in KiB (``VmHWM``, ``VmRSS``); the ``ru_maxrss`` peak when
    the file is unavailable (not Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def overrides(args: argparse.Namespace, grids: int, output_dir: Path) -> list[str]:
    """The ``evaluate.yaml`` overrides of one evaluation on ``grids`` trail grids."""
    return [f"checkpoint={args.checkpoint}", f"categories=[{','.join(args.categories)}]",
            f"levels=[{','.join(str(lv) for lv in args.levels)}]", f"robots_per_cell={args.robots_per_cell}",
            f"variants={args.variants}", "runs=1", f"trail_seeds=[{','.join(str(s) for s in range(grids))}]",
            f"num_threads={args.num_threads}", "device=cpu", "video=false", "logger.backend=csv",
            f"output_dir={output_dir}"]


def child(args: argparse.Namespace) -> None:
    """One evaluation in this process; prints ``{"grids", "peak_kib", "end_kib", "seconds", "episodes"}``."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from hydra import compose, initialize_config_dir

    from legoh_rl.training import eval_run

    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "config"), version_base=None):
        cfg = compose(config_name="evaluate", overrides=overrides(args, args.child, Path(args.output_dir)))
    start = time.perf_counter()
    out = eval_run.evaluate(cfg)
    seconds = time.perf_counter() - start
    print(json.dumps({"grids": args.child, "peak_kib": _status_kib("VmHWM"), "end_kib": _status_kib("VmRSS"),
                      "seconds": round(seconds, 1), "episodes": len(out["episodes"])}), flush=True)


def measure(args: argparse.Namespace, grids: int) -> dict:
    """Run one evaluation on ``grids`` trail grids in a fresh process; its :func:`child` figures."""
    with tempfile.TemporaryDirectory(prefix="eval_memory_") as tmp:
        cmd = [sys.executable, __file__, "--child", str(grids), "--output-dir", tmp,
               "--checkpoint", str(args.checkpoint), "--categories", *args.categories,
               "--levels", *map(str, args.levels), "--robots-per-cell", str(args.robots_per_cell),
               "--variants", str(args.variants), "--num-threads", str(args.num_threads)]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"the evaluation on {grids} grid(s) failed (exit {proc.returncode}):\n{proc.stderr[-4000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", default="checkpoints/student_h1.pt", help="a .pt, .onnx or 'zero'")
    ap.add_argument("--grids", type=int, nargs="+", default=[1, 3], help="trail grid counts to measure")
    ap.add_argument("--categories", nargs="+", default=["randommix", "gap"])
    ap.add_argument("--levels", type=int, nargs="+", default=[0, 2])
    ap.add_argument("--robots-per-cell", type=int, default=2)
    ap.add_argument("--variants", type=int, default=2)
    ap.add_argument("--num-threads", type=int, default=1)
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--output-dir", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if any(g < 1 for g in args.grids):
        ap.error(f"--grids must be positive, got {args.grids}")
    if args.child is not None:
        child(args)
        return
    print(f"checkpoint {args.checkpoint}: categories {args.categories} x levels {args.levels}, "
          f"{args.robots_per_cell} robot(s) per cell, {args.variants} variant(s), {args.num_threads} physics thread(s)")
    print("\n| grids | episodes | peak RSS (MiB) | RSS at end (MiB) | time (s) | peak / first row |")
    print("|---:|---:|---:|---:|---:|---:|")
    first = None
    for grids in args.grids:
        r = measure(args, grids)
        first = first or r["peak_kib"]
        print(f"| {grids} | {r['episodes']} | {r['peak_kib'] / 1024:,.0f} | {r['end_kib'] / 1024:,.0f} | "
              f"{r['seconds']:.0f} | {r['peak_kib'] / first:.2f} |", flush=True)


if __name__ == "__main__":
    main()
