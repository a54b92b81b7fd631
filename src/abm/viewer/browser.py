"""Screenshots of a served page with headless Chromium (software WebGL), for docs and browser tests.

Chromium is driven over the DevTools protocol (its websocket, with the ``websockets`` package viser brings), so
the page runs in real time and a picture can be retaken until it shows what the caller waits for: a viser page
receives its scene over a websocket after it loads, which on a loaded machine can take seconds, and Chromium's
``--virtual-time-budget`` does not wait for websocket traffic.
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

from abm.errors import ExternalError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable on ``PATH`` (``None`` if there is none)."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class _DevTools:
    """A minimal DevTools-protocol client of one page: numbered commands, events skipped."""

    def __init__(self, websocket_url: str, timeout_s: float) -> None:
        from websockets.sync.client import connect

        self.timeout_s = timeout_s
        self.socket = connect(websocket_url, max_size=None, open_timeout=timeout_s)
        self.next_id = 0

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv(timeout=self.timeout_s))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise ExternalError(f"Chromium refused {method}: {message['error']}")
                result: dict[str, Any] = message.get("result", {})
                return result

    def close(self) -> None:
        self.socket.close()


def _devtools_port(process: subprocess.Popen[bytes], profile: Path, log: Path, timeout_s: float) -> int:
    """The port of Chromium's DevTools endpoint, from the ``DevToolsActivePort`` file it writes in its profile."""
    deadline = time.monotonic() + timeout_s
    port_file = profile / "DevToolsActivePort"
    while time.monotonic() < deadline and process.poll() is None:
        lines = port_file.read_text().split() if port_file.is_file() else []
        if lines and lines[0].isdigit():
            return int(lines[0])
        time.sleep(0.1)
    said = log.read_text(errors="replace")[-500:] if log.is_file() else ""
    raise ExternalError(f"Chromium did not open its DevTools endpoint (exit {process.poll()}): {said}")


# Viser tells a page drawn by a software renderer so in a notification that never closes; a screenshot is drawn
# by SwiftShader on purpose, so the notice is hidden there (a person's browser still shows it).
_HIDE_SOFTWARE_NOTICE = """
for (const note of document.querySelectorAll('.mantine-Notification-root')) {
  if (note.textContent.includes('Software WebGL')) { note.style.display = 'none'; }
}
"""


def screenshot(url: str, path: str | Path, width: int = 1400, height: int = 900, wait_ms: int = 8000,
               timeout_s: float = 90.0, ready: Callable[[Path], bool] | None = None,
               settle_s: float = 1.5) -> Path:
    """Open ``url`` in headless Chromium, let it run ``wait_ms`` (real time), and save a PNG at ``path``.

    The picture is retaken until the page has finished drawing: ``ready(path)`` is true (when given) and two
    pictures taken ``settle_s`` apart are identical (a scene still arriving or fading in changes between them),
    or ``timeout_s`` has passed; the last picture is kept either way, so a caller that waits for something to
    be drawn checks the file it gets. WebGL runs in software (SwiftShader), so no GPU or display is needed.
    Raises :class:`~abm.errors.ExternalError` when no Chromium is installed (``apt-get install chromium``) or it
    cannot be driven.
    """
    exe = find_chromium()
    if exe is None:
        raise ExternalError("no Chromium found for screenshots: install it (Debian: apt-get install chromium)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + timeout_s
    with tempfile.TemporaryDirectory(prefix="abm-chromium-") as folder:
        profile, log = Path(folder) / "profile", Path(folder) / "chromium.log"
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu-sandbox", "--use-angle=swiftshader",
               "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run", f"--user-data-dir={profile}",
               f"--window-size={width},{height}", "--remote-debugging-port=0", "about:blank"]
        with log.open("wb") as log_file:
            process = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log_file)
        try:
            port = _devtools_port(process, profile, log, timeout_s)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=timeout_s) as response:
                pages = [t for t in json.load(response) if t.get("type") == "page"]
            if not pages:
                raise ExternalError("Chromium opened no page to draw in")
            page = _DevTools(pages[0]["webSocketDebuggerUrl"], timeout_s)
            try:
                page.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                          mobile=False)
                page.call("Page.navigate", url=url)
                time.sleep(wait_ms / 1000)
                previous = b""
                while True:
                    page.call("Runtime.evaluate", expression=_HIDE_SOFTWARE_NOTICE)
                    picture = base64.b64decode(page.call("Page.captureScreenshot", format="png")["data"])
                    path.write_bytes(picture)
                    settled = picture == previous and (ready is None or ready(path))
                    if settled or time.monotonic() + settle_s > deadline:
                        return path
                    previous = picture
                    time.sleep(settle_s)
            finally:
                page.close()
        finally:
            process.terminate()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
