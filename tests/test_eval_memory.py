"""An evaluation's peak memory does not grow with its number of trail grids (issue 50, part 2).

``recipes/evaluate.py`` builds one env per trail grid (``trail_seeds``); each must be released
before the next is built. The evaluations run in fresh processes (``benchmarks/eval_memory.py
--child``), so each reads its own peak RSS; the two run side by side to halve the wait. The
zero-action policy on one tiny cell shows the growth as well as a student does: before the fix,
three grids peaked ~290 MB (35%) over one (``BENCHMARKS.md``, "Evaluation memory").
"""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLACK_MIB = 24  # allocator noise between two processes doing the same work


def _start(grids: int, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "benchmarks" / "eval_memory.py"), "--child", str(grids),
           "--output-dir", str(out), "--checkpoint", "zero", "--categories", "randommix", "--levels", "0",
           "--robots-per-cell", "1", "--variants", "1", "--num-threads", "1"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _figures(proc: subprocess.Popen, grids: int) -> dict:
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, f"the evaluation on {grids} grid(s) failed:\n{err[-3000:]}"
    figures = json.loads(out.strip().splitlines()[-1])
    assert figures["grids"] == grids and figures["episodes"] == grids  # one robot, one run per grid
    return figures


def test_peak_memory_does_not_grow_with_the_trail_grids(tmp_path):
    one, three = _start(1, tmp_path / "one"), _start(3, tmp_path / "three")
    one, three = _figures(one, 1), _figures(three, 3)
    peak1, peak3 = one["peak_kib"] / 1024, three["peak_kib"] / 1024
    assert peak3 <= 1.1 * peak1 + SLACK_MIB, (
        f"3 trail grids peaked at {peak3:.0f} MiB, 1 grid at {peak1:.0f} MiB: each grid's env must be released "
        "before the next is built")
