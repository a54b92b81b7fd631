"""Screenshots of a served page with headless Chromium (software WebGL), for docs and browser tests."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from abm.errors import ExternalError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable on ``PATH`` (``None`` if there is none)."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def screenshot(url: str, path: str | Path, width: int = 1400, height: int = 900, wait_ms: int = 8000,
               timeout_s: float = 90.0) -> Path:
    """Open ``url`` in headless Chromium, let it run ``wait_ms`` of page time, and save a PNG at ``path``.

    WebGL runs in software (SwiftShader), so no GPU or display is needed. Raises ``RuntimeError`` when no
    Chromium is installed (``apt-get install chromium``) or it writes no picture.
    """
    exe = find_chromium()
    if exe is None:
        raise ExternalError("no Chromium found for screenshots: install it (Debian: apt-get install chromium)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="abm-chromium-") as profile:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu-sandbox", "--use-angle=swiftshader",
               "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run", f"--user-data-dir={profile}",
               f"--window-size={width},{height}", f"--virtual-time-budget={wait_ms}",
               f"--screenshot={path.resolve()}", url]
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    if not path.is_file():
        raise ExternalError(f"Chromium wrote no screenshot (exit {result.returncode}): {result.stderr[-500:]}")
    return path
