"""OpenMP's wait policy for training on shared cores; imported before torch by the training recipes.

Torch runs its CPU operators on OpenMP threads, which by default spin at every barrier. When
another process holds one of the cores (physics threads, a second run, a test suite), a spinning
thread burns the time slice its partner needs, and a 2-thread update becomes slower than a
1-thread one. ``OMP_WAIT_POLICY=PASSIVE`` makes waiting threads sleep instead. Measured on this
project's 2-core machine (``python benchmarks/openmp_wait.py --steps 80``, one run, an Adam step
of the oracle's MLP on 1,536 samples; "one busy": a busy loop in another process):

=======================  ===========  ===============
policy                   cores idle   one core busy
=======================  ===========  ===============
1 thread                 22.2 ms      18.9 ms
2 threads, spinning      13.4 ms      38.8 ms
2 threads, PASSIVE       13.0 ms      18.4 ms
=======================  ===========  ===============

OpenMP reads the variable once, when torch loads it: :func:`set_passive_wait` must run before
the first ``import torch`` of the process. Importing this module does that (it imports nothing
heavy), so a recipe imports it first; worker processes inherit the setting. A value the user
exported is kept.
"""

from __future__ import annotations

import os
import sys

__all__ = ["set_passive_wait"]

VARIABLE = "OMP_WAIT_POLICY"


def set_passive_wait() -> bool:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` unless it is already set.

    Returns:
        True when the policy in force for this process is PASSIVE: the variable is (now) PASSIVE
        and torch was not imported before (OpenMP had not read it yet).
    """
    os.environ.setdefault(VARIABLE, "PASSIVE")
    return os.environ[VARIABLE].upper() == "PASSIVE" and "torch" not in sys.modules


set_passive_wait()
