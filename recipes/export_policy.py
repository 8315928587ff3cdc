"""Slim a training checkpoint down to its policy (for committing or sharing), or export it to ONNX.

    python recipes/export_policy.py outputs/oracle_h1/last.pt checkpoints/oracle_h1.pt
    python recipes/export_policy.py runs/x/last.pt policy.pt --experiment oracle_h1_footholds
    python recipes/export_policy.py runs/x/last.pt policy_ema.pt --weights average
    python recipes/export_policy.py checkpoints/oracle_h1.pt deploy/oracle_h1.onnx --format onnx
    python recipes/export_policy.py checkpoints/student_h1.pt deploy/student_h1.onnx --format onnx

A staged experiment exports its policy by itself (``<checkpoint.dir>/policy.pt``), and every run
records its experiment and stage in the meta block; ``--experiment`` / ``--stage`` set them for a
checkpoint trained before runs recorded them. ``--weights average`` writes the weights' moving
average a training checkpoint carries (``checkpoint.ema_decay``) instead of its raw weights.

``--format onnx`` (needs ``pip install 'legoh-rl[deploy]'``) writes an oracle as one graph
``OUT.onnx`` and a student as two, ``OUT.perception.onnx`` (10 Hz, GRU state as an explicit
input/output) and ``OUT.locomotion.onnx`` (50 Hz), each carrying the meta block; evaluate them
with ``python recipes/evaluate.py checkpoint=OUT.onnx`` (docs/deploy.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from legoh_rl.training.checkpoint import export_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    parser.add_argument("--experiment", help="the experiment that made it (meta block)")
    parser.add_argument("--stage", help="its stage within that experiment (meta block)")
    parser.add_argument("--format", choices=("pt", "onnx"), default="pt",
                        help="pt: a slim torch checkpoint (default); onnx: ONNX graph(s) for onnxruntime")
    parser.add_argument("--weights", choices=("raw", "average"), default="raw",
                        help="raw: the trained weights (default); average: the run's weight average (checkpoint.ema_decay)")
    args = parser.parse_args()
    provenance = {k: v for k, v in (("experiment", args.experiment), ("stage", args.stage)) if v is not None}
    if args.format == "onnx":
        if args.weights != "raw":
            raise SystemExit("error: --weights average writes a .pt policy; export that file to ONNX")
        from legoh_rl.training.onnx_export import export_onnx

        try:
            outs = export_onnx(args.src, args.dst, provenance)
        except ImportError as err:
            raise SystemExit(f"error: {err}") from None
        for name, out in outs.items():
            print(f"{args.src} -> {out} ({name}, {out.stat().st_size / 1e6:.2f} MB)")
        return
    out = export_policy(args.src, args.dst, provenance, average=args.weights == "average")
    print(f"{args.src} ({args.src.stat().st_size / 1e6:.2f} MB) -> {out} ({out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
