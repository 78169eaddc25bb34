"""The tree passes ``ruff check`` with the rule set pinned in pyproject.toml ([tool.ruff]; ruff
itself is pinned in the ``dev`` extra, so the rules do not move under the code)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _ruff() -> str | None:
    """The ruff beside this interpreter (a venv's bin/), else one on PATH; None when absent."""
    here = Path(sys.executable).with_name("ruff")
    return str(here) if here.is_file() else shutil.which("ruff")


def _pinned_version() -> str:
    """The version of ruff the ``dev`` extra pins (``ruff==X``)."""
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    pins = [m.group(1) for d in dev if (m := re.fullmatch(r"ruff==(\S+)", d.replace(" ", "")))]
    assert len(pins) == 1, f"the dev extra must pin ruff exactly once: {dev}"
    return pins[0]


def test_ruff_check_is_clean():
    pinned = _pinned_version()
    ruff = _ruff()
    if ruff is None:
        pytest.skip("ruff is not installed (pip install -e '.[dev]')")
    version = subprocess.run([ruff, "--version"], capture_output=True, text=True, timeout=60,
                             check=False).stdout.split()
    if version[-1:] != [pinned]:  # another version has other default rules
        pytest.skip(f"ruff {' '.join(version[1:])} is not the pinned {pinned}")
    proc = subprocess.run([ruff, "check", "--no-cache", "--output-format", "concise", "src", "tests",
                           "benchmarks"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          check=False)
    assert proc.returncode == 0, f"ruff check found problems:\n{proc.stdout}{proc.stderr}"
