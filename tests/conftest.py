"""Shared fixtures. Tests that need the real data in ../shared/data skip cleanly when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("AEROTRACK_SHARED", REPO.parent / "shared")) / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path to ../shared/data; skips the test when it is not beside the checkout."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside the checkout")
    return SHARED_DATA


def ctrl_c_track_at(monkeypatch, frame: int) -> None:
    """Make the next ``aerotrack track`` in this process get a SIGINT once ``frame`` frames are
    done (as a user's Ctrl-C, through the signal handler), via its progress callback."""
    import os
    import signal

    from aerotrack.cli import track_cmd

    made = track_cmd.make_progress

    def with_ctrl_c(*args, **kwargs):
        progress, close = made(*args, **kwargs)

        def wrapped(done):
            progress(done)
            if done == frame:
                os.kill(os.getpid(), signal.SIGINT)
        return wrapped, close

    monkeypatch.setattr(track_cmd, "make_progress", with_ctrl_c)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """Run the ``aerotrack`` CLI in-process: (exit code, stdout, stderr). Arguments may be paths."""
    from aerotrack.cli.main import main

    capsys.readouterr()
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err
