"""Headless Chromium for the browser viewer: open its page, wait for the scene, take screenshots.

:class:`HeadlessChromium` starts Debian's ``chromium`` (or Chrome) without a display, with
software WebGL (SwiftShader), and drives it over the Chrome DevTools Protocol with a plain
websocket (the ``websockets`` package, which viser installs). It is what
``recipes/play.py screenshot=PATH`` uses to picture the viewer on a headless box, and what the
viewer's browser test loads the page with.

Chromium's own ``--screenshot`` flag captures when the page's virtual time runs out, which for a
page that fills itself over a websocket is often before the scene has arrived;
:meth:`HeadlessChromium.wait_for_scene` instead captures until the page shows a scene.
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

__all__ = ["CHROMIUM_HINT", "HeadlessChromium", "changed_fraction", "find_chromium", "scene_stats"]

#: how to install the browser
CHROMIUM_HINT = "install Chromium (Debian/Ubuntu: apt-get install chromium)"
_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
          "--disable-quic", "--no-first-run", "--no-default-browser-check", "--disable-background-networking",
          "--disable-component-update", "--disable-sync", "--disable-extensions", "--mute-audio",
          "--hide-scrollbars", "--remote-debugging-port=0")


def find_chromium(binary: str | os.PathLike | None = None) -> str:
    """The Chromium (or Chrome) executable: ``binary``, or the first of ``chromium``,
    ``chromium-browser``, ``google-chrome`` on the PATH.

    Raises:
        FileNotFoundError: none found; names what was looked for and how to install it.
    """
    if binary is not None:
        if Path(binary).is_file() and os.access(binary, os.X_OK):
            return str(binary)
        raise FileNotFoundError(f"no Chromium executable at {binary}; {CHROMIUM_HINT}")
    for name in _NAMES:
        found = shutil.which(name)
        if found:
            return found
    raise FileNotFoundError(f"no Chromium on the PATH (looked for {', '.join(_NAMES)}); {CHROMIUM_HINT}")


def scene_stats(png: bytes, box: tuple[float, float, float, float] = (0.0, 0.0, 0.6, 1.0)) -> dict:
    """How much a screenshot shows, in the part ``box`` (left, top, right, bottom as fractions of
    the width and height; default the left 60 %, clear of the viewer's control panel).

    Returns:
        ``{"colors": distinct RGB colours, "drawn": fraction of pixels that are not the blank
        page's white (any channel below 235)}``.
    """
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    h, w = image.shape[:2]
    x0, y0, x1, y1 = (int(round(f * n)) for f, n in zip(box, (w, h, w, h), strict=True))
    part = image[y0:y1, x0:x1].reshape(-1, 3)
    colors = np.unique(part.astype(np.int32) @ np.array([65536, 256, 1]))
    return {"colors": int(colors.size), "drawn": float((part < 235).any(axis=1).mean())}


class HeadlessChromium:
    """A headless Chromium showing one page, driven over the DevTools protocol (a context manager).

    Args:
        url: the page to open.
        binary: the executable (default: :func:`find_chromium`).
        width, height: the window, pixels.
        timeout: seconds to wait for the browser to start and for each command.

    Raises:
        FileNotFoundError: no Chromium (names how to install it).
        ImportError: no ``websockets`` package (``pip install 'legoh-rl[viewer]'``).
        RuntimeError: the browser did not start (with the end of its log).
    """

    def __init__(self, url: str, binary: str | os.PathLike | None = None, width: int = 1024, height: int = 768,
                 timeout: float = 60.0) -> None:
        try:
            from websockets.sync.client import connect
        except ImportError as err:
            raise ImportError("driving Chromium needs the websockets package: pip install 'legoh-rl[viewer]' "
                              f"[{err}]") from err
        self.width, self.height, self.timeout = int(width), int(height), float(timeout)
        self._profile = tempfile.TemporaryDirectory(prefix="legoh_chromium_")
        self._log = open(Path(self._profile.name) / "chromium.log", "wb")  # noqa: SIM115 (closed in close())
        self._process = subprocess.Popen(
            [find_chromium(binary), *_FLAGS, f"--user-data-dir={self._profile.name}",
             f"--window-size={self.width},{self.height}", url],
            stdout=self._log, stderr=subprocess.STDOUT,
            start_new_session=True)  # its own process group: close() stops its helper processes too
        self._ids = itertools.count(1)
        self._ws = None
        try:
            port = self._devtools_port()
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=self.timeout) as reply:
                pages = [t for t in json.load(reply) if t.get("type") == "page"]
            if not pages:
                raise RuntimeError("Chromium started without a page")
            self._ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=self.timeout)
            self.call("Emulation.setDeviceMetricsOverride", width=self.width, height=self.height,
                      deviceScaleFactor=1, mobile=False)
        except BaseException:
            self.close()
            raise

    def _devtools_port(self) -> int:
        """The DevTools port Chromium chose (written to its profile folder when it is ready)."""
        path = Path(self._profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                raise RuntimeError(f"Chromium exited with code {self._process.returncode}: {self._log_tail()}")
            if path.is_file():
                lines = path.read_text().split()
                if lines and lines[0].isdigit():
                    return int(lines[0])
            time.sleep(0.1)
        raise RuntimeError(f"Chromium did not open its DevTools port within {self.timeout:.0f} s: {self._log_tail()}")

    def _log_tail(self) -> str:
        self._log.flush()
        text = (Path(self._profile.name) / "chromium.log").read_bytes().decode(errors="replace")
        return text[-1500:] or "(no output)"

    def call(self, method: str, **params) -> dict:
        """Send one DevTools command and return its result (events in between are dropped).

        Raises:
            RuntimeError: the browser answered with an error (names the method).
            TimeoutError: no answer within the timeout.
        """
        ident = next(self._ids)
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        deadline = time.monotonic() + self.timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"Chromium did not answer {method} within {self.timeout:.0f} s")
            message = json.loads(self._ws.recv(timeout=left))
            if message.get("id") == ident:
                if "error" in message:
                    raise RuntimeError(f"Chromium refused {method}: {message['error']}")
                return message.get("result", {})

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    def screenshot(self, path: str | os.PathLike | None = None) -> bytes:
        """A PNG of the page as it is now (also written to ``path`` when given)."""
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).write_bytes(png)
        return png

    def wait_for_scene(self, min_drawn: float = 0.6, min_colors: int = 1000, settle: float = 1.5,
                       timeout: float = 60.0, changed_from: bytes | None = None, min_changed: float = 0.05) -> bytes:
        """Screenshots until the page shows a scene (see :func:`scene_stats`): at least
        ``min_drawn`` of the left part drawn in at least ``min_colors`` colours (and, with
        ``changed_from``, at least ``min_changed`` of its pixels different from that earlier
        screenshot); then waits ``settle`` seconds for the rest to arrive and returns a last one.

        Raises:
            TimeoutError: no such scene within ``timeout`` seconds (names what the last
                screenshot showed).
        """
        deadline = time.monotonic() + timeout
        stats, changed = {}, None
        while time.monotonic() < deadline:
            png = self.screenshot()
            stats = scene_stats(png)
            changed = None if changed_from is None else changed_fraction(changed_from, png)
            if stats["drawn"] >= min_drawn and stats["colors"] >= min_colors and (
                    changed is None or changed >= min_changed):
                time.sleep(settle)
                return self.screenshot()
            time.sleep(1.0)  # each screenshot draws a frame, which costs a software renderer dearly
        raise TimeoutError(f"the page showed no scene within {timeout:.0f} s: last screenshot {stats}"
                           + ("" if changed is None else f", {changed:.1%} of it changed"))

    def hide_notifications(self) -> None:
        """Remove the page's pop-up notifications (viser's "software WebGL" notice, for a
        picture of the scene)."""
        self.evaluate("document.querySelectorAll('[class*=\"mantine-Notification\"]').forEach(e => e.remove())")

    def close(self) -> None:
        """Stop the browser and delete its profile (idempotent)."""
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # the browser may be gone already
                pass
            self._ws = None
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        try:  # Chromium's helpers (crashpad, utility processes) can outlive it and still write the profile
            os.killpg(self._process.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        if not self._log.closed:
            self._log.close()
        for _ in range(10):  # a helper being reaped may write one last file while the profile is removed
            try:
                self._profile.cleanup()
                return
            except OSError:
                time.sleep(0.2)
        shutil.rmtree(self._profile.name, ignore_errors=True)

    def __enter__(self) -> HeadlessChromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def changed_fraction(a: bytes, b: bytes, box: tuple[float, float, float, float] = (0.0, 0.0, 0.6, 1.0)) -> float:
    """Fraction of the pixels in ``box`` (as :func:`scene_stats`) that differ by more than 24 in
    some channel between two same-size screenshots."""
    from PIL import Image

    x, y = (np.asarray(Image.open(io.BytesIO(p)).convert("RGB")).astype(np.int32) for p in (a, b))
    if x.shape != y.shape:
        return 1.0
    h, w = x.shape[:2]
    x0, y0, x1, y1 = (int(round(f * n)) for f, n in zip(box, (w, h, w, h), strict=True))
    return float((np.abs(x[y0:y1, x0:x1] - y[y0:y1, x0:x1]) > 24).any(axis=-1).mean())
