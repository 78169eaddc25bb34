"""Open a report in headless Chromium: its DOM after scripts ran, its console messages, a
screenshot. Used by the tests and to make the documentation's screenshot; needs a ``chromium``
executable (Debian package ``chromium``), never downloads one.

Chromium runs isolated: a fresh profile folder, no network services (``--disable-background-
networking``, ``--disable-component-update``, ``--disable-sync``), no GPU, virtual time so that
page scripts finish deterministically.
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import StageError

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--disable-extensions", "--mute-audio", "--hide-scrollbars"]
_CONSOLE = re.compile(r":CONSOLE(?::|\()\d*\)?\]\s*(.*)")


def find_chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


@dataclass
class PageLoad:
    """What Chromium saw: the serialised DOM, console messages, and the page's self-check."""

    dom: str
    console: list[str]
    selfcheck: dict | None


def _run(url_or_path: str | Path, extra: list[str], timeout: float, budget_ms: int) -> subprocess.CompletedProcess:
    exe = find_chromium()
    if exe is None:
        raise StageError("no chromium executable found (apt-get install chromium)")
    target = Path(url_or_path).resolve().as_uri() if not str(url_or_path).startswith("file:") else str(url_or_path)
    with tempfile.TemporaryDirectory(prefix="aerotrack-chromium-") as profile:
        args = [exe, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
                f"--virtual-time-budget={budget_ms}", *extra, target]
        try:
            return subprocess.run(args, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            raise StageError(f"chromium did not finish within {timeout:.0f} s") from None


def load_page(path: str | Path, *, timeout: float = 120.0, budget_ms: int = 15000) -> PageLoad:
    """Load a local HTML file; return its DOM after scripts ran and its console messages."""
    proc = _run(path, ["--dump-dom"], timeout, budget_ms)
    console = [m.group(1) for line in proc.stderr.splitlines() if (m := _CONSOLE.search(line))]
    sc = re.search(r'data-selfcheck="([^"]*)"', proc.stdout)
    selfcheck = json.loads(html.unescape(sc.group(1))) if sc else None
    return PageLoad(proc.stdout, console, selfcheck)


def screenshot(path: str | Path, png: str | Path, *, width: int = 1280, height: int = 1800,
               timeout: float = 120.0, budget_ms: int = 15000) -> Path:
    """Save a PNG screenshot of the top ``width`` x ``height`` CSS pixels of a local HTML file."""
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    _run(path, [f"--screenshot={png}", f"--window-size={width},{height}"], timeout, budget_ms)
    if not png.is_file():
        raise StageError(f"chromium wrote no screenshot to {png}")
    return png
