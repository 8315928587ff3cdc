"""MuJoCo's own viewer on a :class:`~legoh_rl.viewer.session.PlaySession` (``viewer=native``).

:func:`run_native` opens ``mujoco.viewer.launch_passive`` on the session's model: the window
shows the first robot's world (MuJoCo draws the terrain, its obstacles and the robot), with the
other robots, P_A (green), P_B (red), the waypoint (yellow), the expert goals (blue, the current
one bright) and a student's anticipated goals (translucent magenta) added as decorations
(:func:`draw_overlay`). Keys: space pauses, backspace puts the robots back at P_A, Tab and
Shift-Tab show MuJoCo's panels; the mouse turns the camera as in MuJoCo's viewer.

It needs a display (MuJoCo's window is a GLFW window): on a headless or remote machine use the
browser viewer instead (``viewer=browser``, the default).
"""

from __future__ import annotations

import os
import sys
import time

import mujoco
import numpy as np

from legoh_rl.viewer.session import PlaySession, Snapshot

__all__ = ["NoDisplayError", "check_display", "draw_overlay", "run_native"]

_KEY_SPACE, _KEY_BACKSPACE = 32, 259  # GLFW key codes
_START, _END, _WAYPOINT = (0.16, 0.67, 0.27, 1.0), (0.84, 0.2, 0.18, 1.0), (0.94, 0.78, 0.16, 1.0)
_GOAL, _GOAL_NOW, _ANTICIPATED = (0.27, 0.43, 0.78, 1.0), (0.16, 0.78, 1.0, 1.0), (0.86, 0.24, 0.86, 0.5)


class NoDisplayError(RuntimeError):
    """``viewer=native`` on a machine without a display."""


def check_display(environ: dict | None = None, platform: str | None = None) -> None:
    """Refuse to open MuJoCo's window without a display (Linux: neither ``DISPLAY`` nor
    ``WAYLAND_DISPLAY`` set).

    Raises:
        NoDisplayError: naming the unset variable and the browser viewer as the way out.
    """
    environ = os.environ if environ is None else environ
    platform = sys.platform if platform is None else platform
    if platform.startswith("linux") and not (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")):
        raise NoDisplayError(
            "viewer=native opens MuJoCo's window, which needs a display, but DISPLAY is unset (a headless or "
            "remote machine): use the browser viewer (viewer=browser, the default, then open its address, through "
            "an SSH tunnel if need be), or run where a display is (a desktop session, ssh -X)")


def _sphere(scene: mujoco.MjvScene, pos, radius: float, rgba) -> None:
    """Add one sphere to ``scene`` (ignored when the scene is full)."""
    if scene.ngeom >= scene.maxgeom:
        return
    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], int(mujoco.mjtGeom.mjGEOM_SPHERE), np.array([radius, 0.0, 0.0]),
                        np.asarray(pos, dtype=np.float64), np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
    scene.ngeom += 1


def draw_overlay(scene: mujoco.MjvScene, session: PlaySession, snap: Snapshot, scratch: mujoco.MjData | None = None,
                 option: mujoco.MjvOption | None = None) -> int:
    """Decorate ``scene`` (a viewer's ``user_scn``): the robots but the first (their moving geoms,
    from ``scratch``, a spare ``MjData``), each robot's P_A, P_B, waypoint and expert goals, and a
    student's anticipated goals. Replaces what the scene held; returns how many geoms it holds."""
    scene.ngeom = 0
    model = session.base.worlds.model
    if session.num_robots > 1:
        scratch = mujoco.MjData(model) if scratch is None else scratch
        option = mujoco.MjvOption() if option is None else option
        perturb = mujoco.MjvPerturb()
        for w in range(1, session.num_robots):
            session.base.worlds.world_data(w, scratch)
            mujoco.mjv_addGeoms(model, scratch, option, perturb, int(mujoco.mjtCatBit.mjCAT_DYNAMIC), scene)
    for w in range(session.num_robots):
        _sphere(scene, snap.start[w], 0.14, _START)
        _sphere(scene, snap.end[w], 0.14, _END)
        _sphere(scene, snap.waypoint[w], 0.11, _WAYPOINT)
        for j in range(int(snap.num_expert_goals[w])):
            _sphere(scene, snap.expert_goals[w, j], 0.07, _GOAL_NOW if j == snap.goal_index[w] else _GOAL)
        if snap.anticipated_goals is not None:
            for p in snap.anticipated_goals[w]:
                _sphere(scene, p + [0.0, 0.0, 0.35], 0.17, _ANTICIPATED)
    return scene.ngeom


def run_native(session: PlaySession, speed: float = 1.0, seconds: float | None = None) -> None:
    """Show ``session`` in MuJoCo's viewer until its window is closed (or ``seconds`` of wall
    time pass), stepping it at ``speed`` x real time at most.

    Raises:
        NoDisplayError: no display (:func:`check_display`).
        ValueError: a speed outside (0, 1].
    """
    if not (isinstance(speed, int | float) and not isinstance(speed, bool) and 0.0 < speed <= 1.0):
        raise ValueError(f"speed must be a number in (0, 1] (a fraction of real time), got {speed!r}")
    check_display()
    import mujoco.viewer

    model = session.base.worlds.model
    data, scratch = mujoco.MjData(model), mujoco.MjData(model)
    state = {"paused": False, "reset": False}

    def on_key(key: int) -> None:
        if key == _KEY_SPACE:
            state["paused"] = not state["paused"]
        elif key == _KEY_BACKSPACE:
            state["reset"] = True

    snap = session.snapshot()
    with mujoco.viewer.launch_passive(model, data, key_callback=on_key, show_left_ui=False,
                                      show_right_ui=False) as viewer:  # Tab / Shift-Tab show MuJoCo's panels
        end = None if seconds is None else time.perf_counter() + float(seconds)  # from when the window is up
        viewer.cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        viewer.cam.trackbodyid = session.base.built.torso_body_id
        viewer.cam.distance, viewer.cam.elevation, viewer.cam.azimuth = 4.0, -20.0, 135.0
        due = time.perf_counter()
        while viewer.is_running() and (end is None or time.perf_counter() < end):
            if state["reset"]:
                state["reset"] = False
                snap = session.reset()
            elif not state["paused"]:
                snap = session.step()
            with viewer.lock():
                session.base.worlds.world_data(0, data)
                draw_overlay(viewer.user_scn, session, snap, scratch, viewer.opt)
            viewer.sync()
            due += session.dt / speed
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                due = time.perf_counter()
