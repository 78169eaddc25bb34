"""Reading small text inputs (control points, telemetry, intrinsics, regions) with one-line errors."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def read_text(path: str | Path, label: str) -> str:
    """The file's text (UTF-8, a BOM tolerated); ``label`` (option and path) starts every message.

    Raises
    ------
    InputError
        The file is missing, unreadable or not UTF-8.
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{label}: is a folder, expected a file")
    if not p.is_file():
        raise InputError(f"{label}: file not found")
    try:
        return p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{label}: cannot read ({exc})") from None
