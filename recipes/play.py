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

from legoh_rl.envs.robots import ROBOTS
from legoh_rl.envs.trails import ALL_CATEGORIES, NUM_LEVELS
from legoh_rl.training.config_checks import (
    Choice,
    Flag,
    Integer,
    ListOf,
    Name,
    Number,
    check_known_keys,
    check_settings,
    recipe_keys,
)
from legoh_rl.training.device import resolve_device
from legoh_rl.viewer.native import check_display, run_native
from legoh_rl.viewer.session import MAX_ROBOTS, PlaySession

VIEWERS = ("browser", "native")
SCREENSHOT_SECONDS = 3.0
CONFIG_FILE = Path(__file__).resolve().parent / "config" / "play.yaml"

#: ``play.yaml``'s settings by kind (``legoh_rl/training/config_checks.py``); ``checkpoints``,
#: ``device`` and ``screenshot_size`` have their own checks in :func:`validate`
SETTINGS = {
    "checkpoint": Name(),
    "robot": Choice(tuple(ROBOTS), nullable=True, what="robot"),
    "category": Choice(ALL_CATEGORIES, what="trail category"),
    "level": Integer(0, NUM_LEVELS - 1),
    "variant": Integer(0),
    "num_robots": Integer(1, MAX_ROBOTS),
    "seed": Integer(0),
    "viewer": Choice(VIEWERS, what="viewer"),
    "host": Name(),
    "port": Integer(0, 65535, text="an integer in [0, 65535] (0: any free port)"),
    "speed": Number(0.0, 1.0, low_open=True),
    "follow": Flag(),
    "device": Name(),
    "seconds": Number(0.0, low_open=True, nullable=True),
    "screenshot": Name(nullable=True),
    "screenshot_size": ListOf(Integer(64)),
}


def validate(cfg: DictConfig) -> None:
    """Check every setting before any work (no policy loaded, no trail built, no port opened), each
    refusal naming the key and the value: ``checkpoint`` given, no key that ``play.yaml`` does not
    have, :data:`SETTINGS` of their kind, ``checkpoints`` a mapping of robot names to checkpoints,
    ``device`` a device of this machine and ``screenshot_size`` two sizes.

    Raises:
        ValueError: the first bad setting.
    """
    if cfg.get("checkpoint") is None:
        raise ValueError("checkpoint is required: a .pt file from a recipe (checkpoints/student_h1.pt), a .onnx "
                         "export, or 'zero' for the PD-hold baseline")
    check_known_keys(cfg, recipe_keys(CONFIG_FILE), open_sections=("checkpoints",), name="play's config")
    check_settings(cfg, SETTINGS)
    checkpoints = cfg.get("checkpoints")
    if checkpoints is not None:
        if not isinstance(checkpoints, DictConfig | dict):
            raise ValueError(f"checkpoints must map robot names to checkpoints, got {checkpoints!r}")
        check_settings(cfg, {f"checkpoints.{robot}": Name() for robot in checkpoints})
        unknown = [robot for robot in checkpoints if str(robot).lower() not in ROBOTS]
        if unknown:
            raise ValueError(f"checkpoints: unknown robot {unknown[0]!r}; valid: {list(ROBOTS)}")
    resolve_device(cfg.device)  # an unknown name, or a GPU this machine lacks
    if len(cfg.screenshot_size) != 2:
        raise ValueError(f"screenshot_size must be [width, height] in pixels (>= 64), got {list(cfg.screenshot_size)}")


def session_of(cfg: DictConfig) -> PlaySession:
    """The :class:`PlaySession` a config checked by :func:`validate` describes."""
    checkpoints = cfg.get("checkpoints") or {}
    if isinstance(checkpoints, DictConfig):
        checkpoints = OmegaConf.to_container(checkpoints, resolve=True)
    return PlaySession(cfg.checkpoint, robot=cfg.robot, category=cfg.category, level=cfg.level, variant=cfg.variant,
                       num_robots=cfg.num_robots, seed=cfg.seed, device=resolve_device(cfg.device),
                       checkpoints=checkpoints)


def play(cfg: DictConfig) -> dict:
    """Run the viewer ``cfg`` asks for (every setting checked first: :func:`validate`); returns what
    it did (``viewer``, ``url``, ``screenshot``, ``steps``) once it stops."""
    validate(cfg)
    seconds = None if cfg.seconds is None else float(cfg.seconds)
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
    session = session_of(cfg)
    try:
        viewer = WebViewer(session, host=str(cfg.host), port=cfg.port, speed=cfg.speed, follow=bool(cfg.follow))
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
