"""Shared test setup: offline robot models from ../shared/robots when MENAGERIE_ROOT is unset."""

import os
from pathlib import Path

_SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "robots"
if "MENAGERIE_ROOT" not in os.environ and (_SHARED / "unitree_h1").is_dir():
    os.environ["MENAGERIE_ROOT"] = str(_SHARED)
os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("MUJOCO_GL", "egl")  # off-screen rendering for the evaluation video
