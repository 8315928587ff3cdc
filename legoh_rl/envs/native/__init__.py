"""Native (C) kernels of the depth camera, built on first use; see :mod:`.build` and :mod:`.march`."""

from legoh_rl.envs.native.build import load_library, unavailable_reason
from legoh_rl.envs.native.march import camera_native, march_ground_native, same_grid

__all__ = ["load_library", "unavailable_reason", "march_ground_native", "camera_native", "same_grid"]
