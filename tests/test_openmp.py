"""OpenMP's wait policy (legoh_rl/openmp.py): set before torch loads, by the training recipes."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _fresh(code: str, **env: str) -> str:
    """stdout of ``code`` in a fresh interpreter (no OMP_WAIT_POLICY unless given in ``env``)."""
    base = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env={**base, **env}, cwd=ROOT, check=True,
                         capture_output=True, text=True)
    return out.stdout.strip()


def test_import_sets_passive_before_torch():
    out = _fresh("import os, sys; import legoh_rl.openmp as m; "
                 "print(os.environ['OMP_WAIT_POLICY'], 'torch' in sys.modules, m.set_passive_wait())")
    assert out == "PASSIVE False True"


def test_user_setting_is_kept():
    out = _fresh("import os; import legoh_rl.openmp as m; print(os.environ['OMP_WAIT_POLICY'], m.set_passive_wait())",
                 OMP_WAIT_POLICY="ACTIVE")
    assert out == "ACTIVE False"


def test_too_late_after_torch():
    out = _fresh("import torch; import legoh_rl.openmp as m; print(m.set_passive_wait())")
    assert out == "False"


@pytest.mark.parametrize("recipe", ["oracle_ppo.py", "unified.py"])
def test_training_recipes_import_it_first(recipe):
    """The first import of each training recipe (after ``__future__``) is legoh_rl.openmp, so it
    runs before anything loads torch."""
    tree = ast.parse((ROOT / "recipes" / recipe).read_text())
    imports = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))
               and not (isinstance(n, ast.ImportFrom) and n.module == "__future__")]
    first = imports[0]
    assert isinstance(first, ast.Import) and first.names[0].name == "legoh_rl.openmp"


def test_recipe_process_has_passive_policy():
    """Importing a training recipe as its script does (recipes/ on the path) leaves the policy set."""
    out = _fresh("import os, sys; sys.path.insert(0, 'recipes'); import oracle_ppo; print(os.environ['OMP_WAIT_POLICY'])")
    assert out == "PASSIVE"


def test_benchmark_times_a_fresh_process():
    """benchmarks/openmp_wait.py's timing child runs under the policy it is given."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import openmp_wait
    finally:
        sys.path.pop(0)
    assert openmp_wait.timed(1, "PASSIVE", 2) > 0
    with pytest.raises(subprocess.CalledProcessError):
        openmp_wait.timed(0, None, 2)  # torch refuses 0 threads: the child's error reaches the caller
