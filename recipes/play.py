"""Watch a policy hike, live, on a trail of your choice: in the browser, or in MuJoCo's window.

    python recipes/play.py checkpoint=checkpoints/student_h1.pt category=gap level=2
    python recipes/play.py checkpoint=checkpoints/oracle_h1.pt category=forest level=3 num_robots=4
    python recipes/play.py checkpoint=deploy/student_h1.onnx                  # an ONNX export
    python recipes/play.py checkpoint=checkpoints/oracle_h1.pt viewer=native  # MuJoCo's viewer (a display)
    python recipes/play.py checkpoint=... screenshot=docs/img/viewer.png      # a PNG of the page, headless

The policy runs as ``recipes/evaluate.py`` runs it (the same loaders, the eval-mode env, the
deterministic action) on the benchmark's trail tile (category, level, variant) of ``seed``.

``viewer=browser`` (the default) serves a page with viser (``pip install 'legoh-rl[viewer]'``): open
the printed address in a browser, on this machine or through ``ssh -L 8080:localhost:8080`` to a
remote one. It shows the trail, the robots, P_A, P_B, the waypoint, the expert goals and, for a
student, its anticipated goals g_1..g_N and its depth image; live metrics; and controls for the
robot, category, level and variant (each rebuilds the trail), reset, pause and speed.
``viewer=native`` opens ``mujoco.viewer`` instead, where a display exists.

``screenshot=PATH`` lets the robots walk ``seconds`` of simulated time (default 3), saves what the
page shows in headless Chromium (Debian: ``apt-get install chromium``) and exits: a picture of a
policy from a machine without a screen.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from legoh_rl.viewer.native import check_display, run_native
from legoh_rl.viewer.session import PlaySession

VIEWERS = ("browser", "native")
SCREENSHOT_SECONDS = 3.0


def session_of(cfg: DictConfig) -> PlaySession:
    """The :class:`PlaySession` a config describes (every value checked there)."""
    checkpoints = cfg.get("checkpoints") or {}
    if isinstance(checkpoints, DictConfig):
        checkpoints = OmegaConf.to_container(checkpoints, resolve=True)
    if not isinstance(checkpoints, dict):
        raise ValueError(f"checkpoints must map robot names to checkpoints, got {checkpoints!r}")
    return PlaySession(cfg.checkpoint, robot=cfg.robot, category=cfg.category, level=cfg.level, variant=cfg.variant,
                       num_robots=cfg.num_robots, seed=cfg.seed, device=cfg.device, checkpoints=checkpoints)


def _seconds(cfg: DictConfig) -> float | None:
    value = cfg.get("seconds")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise ValueError(f"seconds must be a positive number (or null), got {value!r}")
    return float(value)


def play(cfg: DictConfig) -> dict:
    """Run the viewer ``cfg`` asks for; returns what it did (``viewer``, ``url``, ``screenshot``,
    ``steps``) once it stops."""
    if cfg.checkpoint is None:
        raise ValueError("checkpoint is required: a .pt file from a recipe (checkpoints/student_h1.pt), a .onnx "
                         "export, or 'zero' for the PD-hold baseline")
    if cfg.viewer not in VIEWERS:
        raise ValueError(f"unknown viewer {cfg.viewer!r}; valid: {list(VIEWERS)}")
    seconds = _seconds(cfg)
    if cfg.viewer == "native":
        check_display()  # before the env is built: say at once what is missing
        session = session_of(cfg)
        try:
            run_native(session, speed=cfg.speed, seconds=seconds)
        finally:
            session.close()
        return {"viewer": "native", "steps": session.steps}
    from legoh_rl.viewer.web import WebViewer

    shot = cfg.get("screenshot")
    port = cfg.port
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"port must be an integer in [0, 65535] (0: any free port), got {port!r}")
    session = session_of(cfg)
    try:
        viewer = WebViewer(session, host=str(cfg.host), port=port, speed=cfg.speed, follow=bool(cfg.follow))
    except BaseException:
        session.close()
        raise
    out = {"viewer": "browser", "url": viewer.url, "screenshot": None}
    try:
        if shot:
            out["screenshot"] = str(screenshot(viewer, Path(shot), SCREENSHOT_SECONDS if seconds is None else seconds,
                                               tuple(cfg.screenshot_size)))
            print(f"saved {out['screenshot']}", flush=True)
        else:
            tunnel = (f"; from another machine: ssh -L {viewer.port}:localhost:{viewer.port} THIS_HOST"
                      if str(cfg.host) in ("127.0.0.1", "localhost") else "")
            print(f"\nwatch at {viewer.url}  ({session.kind} on {session.choice.robot}, {session.choice.category} "
                  f"level {session.choice.level}{tunnel}; Ctrl-C stops)\n", flush=True)
            try:
                viewer.run(seconds=seconds)
            except KeyboardInterrupt:
                pass
    finally:
        viewer.close()
        session.close()
    out["steps"] = session.steps
    return out


def screenshot(viewer, path: Path, seconds: float, size: tuple[int, int]) -> Path:
    """Let the robots walk ``seconds`` (simulated), then save the page as headless Chromium shows it."""
    from legoh_rl.viewer.browser import HeadlessChromium

    if len(size) != 2 or not all(isinstance(v, int) and v >= 64 for v in size):
        raise ValueError(f"screenshot_size must be [width, height] in pixels (>= 64), got {list(size)}")
    for _ in range(int(round(seconds / viewer.session.dt))):  # simulated seconds: the same picture on any machine
        viewer.session.step()
    viewer.draw()  # the last step, metrics and depth image included
    with HeadlessChromium(viewer.url, width=size[0], height=size[1]) as browser:
        browser.wait_for_scene()
        browser.hide_notifications()
        browser.screenshot(path)
    return path


@hydra.main(config_path="config", config_name="play", version_base=None)
def main(cfg: DictConfig) -> None:
    play(cfg)


if __name__ == "__main__":
    main()
