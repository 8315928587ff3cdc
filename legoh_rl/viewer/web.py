"""The browser viewer: a :class:`~legoh_rl.viewer.session.PlaySession` drawn with viser.

:class:`WebViewer` serves a page (``http://HOST:PORT``) that any browser with WebGL opens, on this
machine or through an SSH tunnel to a headless one. It shows

* the trail: MuJoCo's heightfield (shaded by height, so ditches and pits read at a glance) and
  its obstacles, each from the compiled model's geoms (:mod:`legoh_rl.viewer.geometry`);
* the robots: every visual geom of the robot, one batched mesh per geom with one instance per
  robot, posed from the simulation every frame;
* P_A (green), P_B (red), the waypoint (yellow), the expert route and goals (blue; the current
  one bright) and, for a student, its anticipated goals g_1..g_N (translucent magenta bubbles,
  tied to the robot by lines) and its depth image in the side panel;
* live metrics (distance to go, episodes, successes, falls, timeouts, the last outcome) and
  controls: robot, category, level and variant (each rebuilds the env and the trail), reset,
  pause, speed (a fraction of real time) and whether the camera follows the first robot.

The simulation runs in :meth:`WebViewer.run` (the caller's thread); GUI callbacks (viser's
threads) only queue commands, which the loop applies between steps, so the session is never
stepped and rebuilt at once.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

import numpy as np

from legoh_rl.envs.robots import ROBOTS
from legoh_rl.envs.trails import ALL_CATEGORIES, NUM_LEVELS
from legoh_rl.viewer.geometry import quat_rotate, simplify_mesh
from legoh_rl.viewer.session import PlaySession, Snapshot

__all__ = ["WebViewer", "require_viser", "VISER_HINT", "terrain_colors", "depth_image"]

#: how to install the browser viewer's dependency
VISER_HINT = "pip install 'legoh-rl[viewer]'"

_START, _END, _WAYPOINT = (40, 170, 70), (215, 50, 45), (240, 200, 40)
_GOAL, _GOAL_NOW, _ANTICIPATED = (70, 110, 200), (40, 200, 255), (220, 60, 220)
_MARKER_R, _GOAL_R, _BUBBLE_R = 0.14, 0.07, 0.17
_LIFT = 0.03  # route and markers sit this far above the ground, m
_DRAW_HZ, _TEXT_HZ = 30.0, 4.0
#: the robot's meshes are drawn simplified to this grid, m (Menagerie's scans: H1 286k triangles,
#: 62k at 5 mm), which keeps the page light for browsers without a GPU and for slow links
_ROBOT_DETAIL = 0.005
#: where the camera starts, from the first robot at P_A (the trail runs along +x)
_CAMERA_OFFSET, _CAMERA_AIM = np.array([-2.7, -1.6, 1.7]), np.array([1.8, 0.0, -0.4])


class _DroppedHandshakes(logging.Filter):
    """Drops websockets' "opening handshake failed" reports: a browser (headless Chromium's
    preconnect, a page being closed) that opened a connection and left before its request."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "opening handshake failed" not in record.getMessage()


def require_viser():
    """The ``viser`` module; ImportError naming what to install when it is missing."""
    try:
        import viser
    except ImportError as err:
        raise ImportError(f"the browser viewer needs viser, which is not installed: {VISER_HINT} "
                          f"(or view with MuJoCo's own window: viewer=native) [{err}]") from err
    return viser


def terrain_colors(vertices: np.ndarray, rgba: np.ndarray, cell: float = 1.0) -> np.ndarray:
    """Per-vertex colours (V, 3) uint8 of a terrain surface: the ground's colour ``rgba`` shaded
    by height (lower darker, higher lighter, around the median height), with a faint ``cell``-metre
    checkerboard for scale."""
    v = np.asarray(vertices, dtype=np.float64)
    z = v[:, 2] - np.median(v[:, 2])
    shade = np.clip(1.0 + 0.9 * z, 0.35, 1.35)
    checker = ((np.floor(v[:, 0] / cell) + np.floor(v[:, 1] / cell)) % 2) * 0.06 - 0.03
    rgb = np.asarray(rgba, dtype=np.float64)[:3][None] * (shade + checker)[:, None]
    return np.clip(rgb * 255.0, 0, 255).astype(np.uint8)


def depth_image(depth: np.ndarray, scale: int = 3) -> np.ndarray:
    """A depth image (H, W) in [0, 1] (1: as far as the camera reaches, or no return) as an RGB
    picture (H*scale, W*scale, 3) uint8: the returns stretched over matplotlib's ``magma``, near
    bright and far dark; pixels without a return black."""
    from matplotlib import colormaps

    d = np.clip(np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=1.0), 0.0, 1.0)
    hit = d < 0.999
    t = np.zeros_like(d)
    if hit.any():
        lo, hi = d[hit].min(), d[hit].max()
        t[hit] = 1.0 - (d[hit] - lo) / max(hi - lo, 1e-6) * 0.85  # the farthest return still visible
    rgb = (colormaps["magma"](t)[..., :3] * 255.0).astype(np.uint8)
    rgb[~hit] = 0
    return np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)


def _rgb(rgba) -> tuple[int, int, int]:
    """A MuJoCo colour as an 8-bit RGB tuple, dark materials lifted so they keep some shading."""
    c = 0.25 + 0.75 * np.clip(np.asarray(rgba, dtype=np.float64)[:3], 0.0, 1.0)
    return tuple(int(round(x * 255)) for x in c)


class WebViewer:
    """Serve a :class:`PlaySession` to browsers (see the module docstring).

    Args:
        session: the simulation to show (the viewer steps it).
        host: the address to listen on (``127.0.0.1``: this machine only; ``0.0.0.0``: every
            interface).
        port: the port (0: any free one); viser takes the next free one when it is busy (see
            :attr:`port`).
        speed: simulated seconds per wall second, at most (0 < speed <= 1; the GUI's slider).
        follow: the camera follows the first robot.

    Raises:
        ImportError: viser is missing (names ``pip install 'legoh-rl[viewer]'``).
        ValueError: a speed outside (0, 1].
    """

    def __init__(self, session: PlaySession, host: str = "127.0.0.1", port: int = 8080, speed: float = 1.0,
                 follow: bool = True) -> None:
        viser = require_viser()
        if not (isinstance(speed, int | float) and not isinstance(speed, bool) and 0.0 < speed <= 1.0):
            raise ValueError(f"speed must be a number in (0, 1] (a fraction of real time), got {speed!r}")
        self.session = session
        logger = logging.getLogger("websockets.server")
        if logger.getEffectiveLevel() < logging.WARNING:  # each page's connect and close (hydra logs INFO)
            logger.setLevel(logging.WARNING)
        if not any(isinstance(f, _DroppedHandshakes) for f in logger.filters):
            logger.addFilter(_DroppedHandshakes())
        self.server = viser.ViserServer(host=host, port=int(port), verbose=False)
        #: the port the page is served on
        self.port = int(self.server.get_port())
        self.url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{self.port}"
        self.speed = float(speed)
        self.follow = bool(follow)
        self.paused = False
        #: scene rebuilds so far (each trail or robot change adds one)
        self.revision = 0
        #: the last status line shown (errors of a refused control change)
        self.status = ""
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._ready_clients: set[int] = set()
        self._reported: dict[int, np.ndarray] = {}  # each page's last reported camera position
        self._trail_nodes: list = []
        self._light_meshes: dict = {}  # (robot, geom) -> the simplified mesh drawn
        self._robot_nodes: list = []
        self._last_text = 0.0
        self._followed = None
        scene = self.server.scene
        scene.set_up_direction("+z")
        scene.configure_environment_map(hdri="park", background=False, environment_intensity=0.6)
        scene.set_background_image(_sky(), format="png")
        scene.configure_default_lights(enabled=True, cast_shadow=True)
        self._build_gui()
        self.snapshot = session.snapshot()
        self._build_scene(self.snapshot)
        self.server.on_client_connect(self._on_connect)

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui, c = self.server.gui, self.session.choice
        gui.configure_theme(control_width="medium", show_share_button=False)
        self.controls = {}
        with gui.add_folder("Trail"):
            self.controls["robot"] = gui.add_dropdown("robot", tuple(ROBOTS), initial_value=c.robot)
            self.controls["category"] = gui.add_dropdown("category", tuple(ALL_CATEGORIES), initial_value=c.category)
            self.controls["level"] = gui.add_slider("level", min=0, max=NUM_LEVELS - 1, step=1, initial_value=c.level)
            self.controls["variant"] = gui.add_number("variant", initial_value=int(c.variant), min=0, step=1)
        for name, handle in self.controls.items():
            handle.on_update(lambda event, name=name: self._commands.put(("change", {name: event.target.value})))
        with gui.add_folder("Run"):
            reset = gui.add_button("reset")
            reset.on_click(lambda _: self._commands.put(("reset", None)))
            self.controls["reset"] = reset
            pause = gui.add_checkbox("pause", initial_value=False)
            pause.on_update(lambda event: setattr(self, "paused", bool(event.target.value)))
            self.controls["pause"] = pause
            speed = gui.add_slider("speed (x real time)", min=0.05, max=1.0, step=0.05, initial_value=self.speed)
            speed.on_update(lambda event: setattr(self, "speed", max(0.05, float(event.target.value))))
            self.controls["speed"] = speed
            follow = gui.add_checkbox("camera follows robot 0", initial_value=self.follow)
            follow.on_update(lambda event: setattr(self, "follow", bool(event.target.value)))
            self.controls["follow"] = follow
        with gui.add_folder("Metrics"):
            self._metrics = gui.add_markdown("")
        self._status_md = gui.add_markdown("")
        with gui.add_folder("Depth camera (student)") as folder:
            self._depth_folder = folder
            self._depth = gui.add_image(np.zeros((8, 8, 3), dtype=np.uint8), label="what the student sees",
                                        format="png")

    def _sync_controls(self) -> None:
        """Show the session's choice in the controls (after a refused change)."""
        c = self.session.choice
        for name in ("robot", "category", "level", "variant"):
            value = getattr(c, name)
            if self.controls[name].value != value:
                self.controls[name].value = value  # queues a no-op change

    def _set_status(self, text: str) -> None:
        self.status = text
        self._status_md.content = text

    # ------------------------------------------------------------------ scene
    def _remove(self, nodes: list) -> None:
        for node in nodes:
            node.remove()
        nodes.clear()

    def _build_scene(self, snap: Snapshot) -> None:
        """(Re)build the trail's and robots' nodes for the session's current env."""
        scene, s = self.server.scene, self.session
        self._remove(self._trail_nodes)
        self._remove(self._robot_nodes)
        import trimesh

        add = self._trail_nodes.append
        for mesh, pos, quat in s.terrain_meshes:
            name = f"/trail/terrain/{mesh.name}"
            if mesh.kind == "hfield":
                world = quat_rotate(np.asarray(quat, dtype=np.float64)[None], mesh.vertices.astype(np.float64)) + pos
                colors = terrain_colors(world, mesh.rgba)
                tm = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colors, process=False)
                add(scene.add_mesh_trimesh(name, tm, position=pos, wxyz=quat, cast_shadow=False))
            else:
                add(scene.add_mesh_simple(name, mesh.vertices, mesh.faces, color=_rgb(mesh.rgba), position=pos,
                                          wxyz=quat, flat_shading=mesh.kind in ("box", "mesh")))
        for w in range(s.num_robots):
            self._add_lane(w, snap)
        self._goal_colors = None
        for i, mesh in enumerate(s.robot_meshes):
            key = (s.choice.robot, mesh.geom)
            if key not in self._light_meshes:  # simplified once per robot: a trail change keeps them
                self._light_meshes[key] = simplify_mesh(mesh.vertices, mesh.faces, _ROBOT_DETAIL)
            vertices, faces = self._light_meshes[key]
            self._robot_nodes.append(scene.add_batched_meshes_simple(
                f"/robots/{i:02d}_{mesh.name}", vertices, faces, batched_wxyzs=snap.geom_quat[:, i],
                batched_positions=snap.geom_pos[:, i], batched_colors=_rgb(mesh.rgba), lod="off"))
        self._bubbles = self._links = None
        self._labels = []
        self._depth_folder.visible = snap.depth is not None
        self.revision += 1
        self._draw(snap, force_text=True)

    def _add_lane(self, w: int, snap: Snapshot) -> None:
        """Markers of robot ``w``'s trail: P_A, P_B, the waypoint, the expert route and goals."""
        scene, add = self.server.scene, self._trail_nodes.append
        lift = np.array([0.0, 0.0, _LIFT])
        heights = self.session.base.trails.height_at

        def on_ground(p):
            p = np.array(p, dtype=np.float64).reshape(-1, 3)
            p[:, 2] = heights(p[:, :2]) + _LIFT
            return p
        start, end, way = on_ground(snap.start[w])[0], on_ground(snap.end[w])[0], on_ground(snap.waypoint[w])[0]
        goals = on_ground(snap.expert_goals[w, :snap.num_expert_goals[w]])
        for name, p, color, r in (("P_A", start, _START, _MARKER_R), ("P_B", end, _END, _MARKER_R),
                                  ("waypoint", way, _WAYPOINT, 0.8 * _MARKER_R)):
            add(scene.add_icosphere(f"/trail/lane{w}/{name}", radius=r, color=color, position=p + lift * 3))
            if w == 0:
                add(scene.add_label(f"/trail/lane{w}/{name}_label", name, position=p + [0.0, 0.0, 0.45]))
        route = np.concatenate([start[None], goals, end[None]])
        add(scene.add_line_segments(f"/trail/lane{w}/route", np.stack([route[:-1], route[1:]], axis=1),
                                    colors=_GOAL, thickness=0.03))
        if len(goals):
            sphere = _icosphere(_GOAL_R)
            add(scene.add_batched_meshes_simple(
                f"/trail/lane{w}/expert_goals", sphere[0], sphere[1], batched_wxyzs=np.tile([1.0, 0, 0, 0], (len(goals), 1)),
                batched_positions=goals + lift, batched_colors=np.tile(_GOAL, (len(goals), 1)).astype(np.uint8)))

    def _add_bubbles(self, snap: Snapshot) -> None:
        """The student's anticipated goals: a translucent bubble per goal and robot, a line from
        the robot to each, and labels g1..gK at the first robot's (made at the first step that
        has them: the policy writes them when it acts)."""
        scene = self.server.scene
        points = self._bubble_points(snap)
        n, k = points.shape[:2]
        sphere = _icosphere(_BUBBLE_R)
        self._bubbles = scene.add_batched_meshes_simple(
            "/policy/anticipated_goals", sphere[0], sphere[1], batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (n * k, 1)),
            batched_positions=points.reshape(-1, 3), batched_colors=_ANTICIPATED, opacity=0.55, cast_shadow=False,
            receive_shadow=False)
        self._links = scene.add_line_segments("/policy/anticipated_links", self._link_points(snap),
                                              colors=_ANTICIPATED, thickness=0.015)
        self._robot_nodes += [self._bubbles, self._links]
        for j in range(k):
            label = scene.add_label(f"/policy/g{j + 1}", f"g{j + 1}", position=points[0, j] + [0.0, 0.0, 0.25])
            self._labels.append(label)
            self._robot_nodes.append(label)

    def _bubble_points(self, snap: Snapshot) -> np.ndarray:
        p = np.array(snap.anticipated_goals)
        p[..., 2] += 0.35  # floating at about knee height, clear of the ground
        return p

    def _link_points(self, snap: Snapshot) -> np.ndarray:
        bubbles = self._bubble_points(snap)
        n, k = bubbles.shape[:2]
        base = np.repeat(snap.base_pos[:, None], k, axis=1) - [0.0, 0.0, 0.5]
        return np.stack([base.reshape(-1, 3), bubbles.reshape(-1, 3)], axis=1)

    # ------------------------------------------------------------------ drawing
    def draw(self) -> None:
        """Draw the session's current state now (robots, goals, metrics, depth image)."""
        self.snapshot = self.session.snapshot()
        self._draw(self.snapshot, force_text=True)

    def _draw(self, snap: Snapshot, force_text: bool = False) -> None:
        """Pose the robots and bubbles, highlight the current goals, move the camera, and (at a
        few Hz) refresh the metrics and the depth image."""
        with self.server.atomic():
            for i, node in enumerate(self._robot_nodes[:len(self.session.robot_meshes)]):
                node.batched_positions = snap.geom_pos[:, i]
                node.batched_wxyzs = snap.geom_quat[:, i]
            if self._bubbles is None and snap.anticipated_goals is not None:
                self._add_bubbles(snap)
            elif snap.anticipated_goals is not None:
                points = self._bubble_points(snap)
                self._bubbles.batched_positions = points.reshape(-1, 3)
                self._links.points = self._link_points(snap)
                for j, label in enumerate(self._labels):
                    label.position = points[0, j] + [0.0, 0.0, 0.25]
            self._highlight_goals(snap)
        self._follow(snap)
        now = time.perf_counter()
        if force_text or now - self._last_text >= 1.0 / _TEXT_HZ:
            self._last_text = now
            self._aim(self.server.initial_camera, snap)  # where a new page (and "Reset View") starts
            self._metrics.content = self._metrics_text(snap)
            if snap.depth is not None:
                self._depth.image = depth_image(snap.depth[0])

    def _highlight_goals(self, snap: Snapshot) -> None:
        """Colour each lane's current expert goal bright (its node is the lane's last one)."""
        key = tuple(snap.goal_index.tolist())
        if key == self._goal_colors:
            return
        self._goal_colors = key
        lanes = [n for n in self._trail_nodes if n.name.endswith("/expert_goals")]
        for w, node in enumerate(lanes):
            count = int(snap.num_expert_goals[w])
            colors = np.tile(_GOAL, (count, 1)).astype(np.uint8)
            if snap.goal_index[w] < count:
                colors[snap.goal_index[w]] = _GOAL_NOW
            node.batched_colors = colors

    def _metrics_text(self, snap: Snapshot) -> str:
        s, c = self.session, self.session.choice
        rows = "\n".join(f"| {w} | {snap.distance_to_go[w]:.2f} m | {snap.episode_time[w]:.1f} s | "
                         f"{snap.outcome[w] or '-'} |" for w in range(min(s.num_robots, 4)))
        more = f"\n\n(+{s.num_robots - 4} more robots)" if s.num_robots > 4 else ""
        return (f"**{s.kind}** on {c.robot}, {c.category} level {c.level} variant {c.variant}\n\n"
                f"episodes **{snap.episodes}**: successes **{snap.successes}**, falls **{snap.falls}**, "
                f"timeouts **{snap.timeouts}**\n\n"
                f"| robot | to go | time | last |\n|---|---|---|---|\n{rows}{more}")

    def _on_connect(self, client) -> None:
        """A new page: aim its camera at the first robot (:meth:`_settle_camera`); from then on
        the camera may follow the robot."""
        cid = client.client_id

        def reported(camera) -> None:
            self._reported[cid] = np.array(camera.position)

        client.camera.on_update(reported)
        threading.Thread(target=self._settle_camera, args=(client,), daemon=True).start()

    def _settle_camera(self, client, tries: int = 40, every: float = 0.25) -> None:
        """Aim a new page's camera until the page reports it where it was sent. A page drops
        camera commands (and may skip ``initial_camera``) that arrive before its 3D view is up,
        so the first aim can be lost; this repeats it for a while (``tries`` x ``every`` s)."""
        cid = client.client_id
        for _ in range(tries):
            if self._stop.is_set() or cid not in self.server.get_clients():
                return
            seen = self._reported.get(cid)
            if seen is not None:
                target = self.snapshot.base_pos[0] + _CAMERA_OFFSET
                if np.linalg.norm(seen - target) < 0.05:
                    self._ready_clients.add(cid)
                    return
                self._aim(client.camera, self.snapshot)
            time.sleep(every)
        self._ready_clients.add(cid)  # the page keeps its own camera; follow from there

    def _aim(self, camera, snap: Snapshot) -> None:
        """Point ``camera`` (a client's, or the initial one) at the first robot from behind-left."""
        robot = snap.base_pos[0]
        camera.position = robot + _CAMERA_OFFSET
        camera.look_at = robot + _CAMERA_AIM

    def _follow(self, snap: Snapshot) -> None:
        """Translate the clients' cameras with the first robot (keeping their view direction)."""
        now = snap.base_pos[0].copy()
        last, self._followed = self._followed, now
        if not self.follow or last is None:
            return
        clients = [c for cid, c in self.server.get_clients().items() if cid in self._ready_clients]
        if snap.done[0]:  # back at P_A: the camera starts over behind it
            for client in clients:
                self._aim(client.camera, snap)
            return
        delta = np.append(now[:2] - last[:2], 0.0)  # along the ground: a fall does not pull the camera down
        if not np.any(np.abs(delta) > 1e-4):
            return
        for client in clients:
            client.camera.position = client.camera.position + delta

    # ------------------------------------------------------------------ the loop
    def _apply(self, command: str, arg) -> None:
        if command == "reset":
            self.snapshot = self.session.reset()
            self._followed = None
            self._draw(self.snapshot, force_text=True)
            return
        if command == "change":
            if all(getattr(self.session.choice, k) == v for k, v in arg.items()):
                return  # what the session runs already (e.g. a control set back after a refusal)
            self._set_status(f"building {', '.join(f'{k}={v}' for k, v in arg.items())} ...")
            try:
                changed = self.session.change(**arg)
            except (ValueError, FileNotFoundError) as err:
                self._set_status(f"**not changed**: {err}")
                self._sync_controls()
                return
            self._set_status("")
            if changed:
                self.snapshot = self.session.snapshot()
                self._followed = None
                self._build_scene(self.snapshot)
                for cid, client in self.server.get_clients().items():
                    if cid in self._ready_clients:
                        self._aim(client.camera, self.snapshot)

    def process_commands(self) -> int:
        """Apply the queued GUI commands (trail changes, reset); returns how many."""
        done = 0
        while True:
            try:
                command, arg = self._commands.get_nowait()
            except queue.Empty:
                return done
            self._apply(command, arg)
            done += 1

    def run(self, seconds: float | None = None) -> None:
        """Step and draw until :meth:`stop` (or for ``seconds`` of wall time), paced to
        :attr:`speed` x real time (slower when the machine cannot keep up)."""
        end = None if seconds is None else time.perf_counter() + float(seconds)
        due = time.perf_counter()
        last_draw = 0.0
        while not self._stop.is_set() and (end is None or time.perf_counter() < end):
            self.process_commands()
            if self.paused:
                time.sleep(0.05)
                due = time.perf_counter()
                continue
            self.snapshot = self.session.step()
            now = time.perf_counter()
            if now - last_draw >= 1.0 / _DRAW_HZ or self.snapshot.done.any():
                self._draw(self.snapshot)
                last_draw = now
            due += self.session.dt / self.speed
            delay = due - time.perf_counter()
            if delay > 0:
                self._stop.wait(delay)
            else:
                due = time.perf_counter()  # behind: run as fast as the machine allows, no catch-up burst

    def stop(self) -> None:
        """Make :meth:`run` return after its current step (thread-safe)."""
        self._stop.set()

    def close(self) -> None:
        """Stop the loop and the server."""
        self.stop()
        self.server.stop()


def _sky(height: int = 128) -> np.ndarray:
    """A sky behind the scene: (height, 2, 3) uint8, blue at the top fading to haze at the bottom."""
    t = np.linspace(0.0, 1.0, height)[:, None]
    rgb = (1.0 - t) * np.array([96.0, 150.0, 215.0]) + t * np.array([222.0, 232.0, 240.0])
    return np.repeat(rgb[:, None, :], 2, axis=1).astype(np.uint8)


def _icosphere(radius: float) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    return np.asarray(sphere.vertices, dtype=np.float32), np.asarray(sphere.faces, dtype=np.int32)
