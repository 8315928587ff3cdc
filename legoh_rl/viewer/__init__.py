"""Watch a policy hike: a live simulation session and the viewers that draw it.

* :mod:`legoh_rl.viewer.session`: :class:`PlaySession`, the env + policy + step + a
  :class:`Snapshot` of plain arrays (no viewer needed: tests and other front ends read it);
* :mod:`legoh_rl.viewer.geometry`: the MuJoCo model's geoms as triangle meshes and their poses;
* :mod:`legoh_rl.viewer.web`: the browser viewer (viser; ``pip install 'legoh-rl[viewer]'``);
* :mod:`legoh_rl.viewer.native`: MuJoCo's own viewer (``mujoco.viewer``, needs a display);
* :mod:`legoh_rl.viewer.browser`: headless Chromium, to picture the browser viewer.

``python recipes/play.py checkpoint=... category=gap level=2`` runs them (README, "Watch a policy").
"""

from legoh_rl.viewer.session import (
    MAX_ROBOTS,
    LaneTrails,
    PlaySession,
    Snapshot,
    TrailChoice,
    anticipated_goals,
    checkpoint_robot,
)

__all__ = ["MAX_ROBOTS", "LaneTrails", "PlaySession", "Snapshot", "TrailChoice", "anticipated_goals",
           "checkpoint_robot"]
