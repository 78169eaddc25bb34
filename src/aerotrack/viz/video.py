"""Video encoding through the ffmpeg that imageio-ffmpeg ships (libx264, libvpx).

OpenCV's pip build cannot write H.264, and its ``mp4v`` files do not play in browsers; its VP8/VP9
writer refuses the WebM container here. So frames are piped as raw BGR into ffmpeg (an argument list,
never a shell): ``.webm`` becomes VP9 (plays in Chromium and Firefox), ``.mp4`` becomes H.264
(yuv420p, ``+faststart``, plays everywhere).
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Self

import cv2
import numpy as np

from ..errors import InputError, OutputError, StageError

CODECS = {
    ".webm": ["-c:v", "libvpx-vp9", "-b:v", "0", "-crf", "36", "-deadline", "realtime",
              "-cpu-used", "8", "-row-mt", "1"],
    ".mp4": ["-c:v", "libx264", "-preset", "veryfast", "-crf", "23", "-movflags", "+faststart"],
}


def ffmpeg_exe() -> str:
    """Path of imageio-ffmpeg's bundled ffmpeg."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


class VideoEncoder:
    """Write BGR frames to an MP4 (H.264) or WebM (VP9) file.

    Parameters
    ----------
    path : path
        Output file; its suffix chooses the codec (``.mp4`` or ``.webm``).
    size : (int, int)
        (width, height) of the frames that will be written; odd sizes are padded by one pixel
        (yuv420p needs even sizes).
    fps : float

    Use as a context manager; ``write(image)`` once per frame.
    """

    def __init__(self, path: str | Path, size: tuple[int, int], fps: float) -> None:
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in CODECS:
            raise InputError(f"--out {self.path}: unsupported video type {suffix!r}; use .mp4 or .webm")
        self.size = (int(size[0]), int(size[1]))
        self.out_size = (self.size[0] + self.size[0] % 2, self.size[1] + self.size[1] % 2)
        self.fps = float(fps)
        self.frames_written = 0
        self._proc: subprocess.Popen | None = None
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{suffix}")

    def __enter__(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        w, h = self.out_size
        args = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "bgr24",
                "-s", f"{w}x{h}", "-r", f"{self.fps:.6g}", "-i", "-", "-an",
                *CODECS[self.path.suffix.lower()], "-pix_fmt", "yuv420p", str(self._tmp)]
        try:
            self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        except OSError as exc:
            raise StageError(f"cannot start ffmpeg ({exc})") from None
        return self

    def write(self, image: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 BGR frame of the size given to the constructor."""
        if image.shape[1] != self.size[0] or image.shape[0] != self.size[1]:
            image = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA)
        if self.out_size != self.size:
            image = cv2.copyMakeBorder(image, 0, self.out_size[1] - self.size[1], 0,
                                       self.out_size[0] - self.size[0], cv2.BORDER_REPLICATE)
        assert self._proc is not None and self._proc.stdin is not None
        try:
            self._proc.stdin.write(np.ascontiguousarray(image, dtype=np.uint8).tobytes())
        except BrokenPipeError:
            err = self._proc.stderr.read().decode(errors="replace").strip() if self._proc.stderr else ""
            raise OutputError(f"{self.path}: ffmpeg stopped: {err.splitlines()[-1] if err else '?'}") from None
        self.frames_written += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        proc = self._proc
        if proc is None:
            return
        if proc.stdin:
            try:
                proc.stdin.close()
            except BrokenPipeError:
                pass
        err = ""
        if proc.stderr:
            err = proc.stderr.read().decode(errors="replace").strip()
            proc.stderr.close()
        rc = proc.wait()
        if exc_type is not None:
            self._tmp.unlink(missing_ok=True)
            return
        if rc != 0 or self.frames_written == 0:
            self._tmp.unlink(missing_ok=True)
            why = err.splitlines()[-1] if err else ("no frames" if not self.frames_written else f"exit {rc}")
            raise OutputError(f"{self.path}: video encoding failed ({why})")
        self._tmp.replace(self.path)
