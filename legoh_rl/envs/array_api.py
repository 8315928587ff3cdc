"""One namespace of array functions for numpy arrays and torch tensors.

The step state, the body state, the reward terms, the gait clock and the episode metrics are
written once against the array API standard and run on either kind of array: the host step's
float64 numpy state, or the torch tensors of a device-resident step (``env.resident``,
docs/gpu_physics.md) on the simulation's device. numpy's own namespace follows the standard since numpy 2.0 and is used as is (no wrapper
cost on the host path); torch's gets array_api_compat's wrapper, which adds what torch lacks
(python scalars in ``minimum``/``maximum``/``where``, ``astype``, ``axis=`` reductions).
"""

from __future__ import annotations

import numpy as np
from array_api_compat import array_namespace

__all__ = ["namespace_of"]


def namespace_of(x):
    """The array namespace of ``x``: the ``numpy`` module for numpy arrays, array_api_compat's
    ``torch`` namespace for tensors (any device)."""
    return np if isinstance(x, np.ndarray) else array_namespace(x)
