"""Frame sources: a video file or a folder of images, streamed one frame at a time.

Frame n (1-based) is the n-th decoded frame of a video, or the n-th image file in lexicographic order
of names. Never more than one frame is held in memory by a source.

``frames(start, stop, stride)`` is the one way to read a range: an image folder opens only the files
asked for, and a video is *sought* to ``start`` instead of decoded from its first frame. Reading
from frame ``s`` by decoding costs ``s - 1`` decodes before the first frame wanted (0.9 ms each at
480x270 in MPEG-4 part 2, 8 ms at 1920x1080 in H.264, measured on this machine): the last segment
of a segment-parallel run (:mod:`aerotrack.parallel`) or a ``--resume`` late in a long video would
decode nearly the whole video first, and that cost would grow with the video's length.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import queue
import re
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..types import Frame

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm"}
DEFAULT_FOLDER_FPS = 30.0
#: Image folders whose assumed frame rate was named (once per folder and process).
_ASSUMED_RATE: set[Path] = set()


class FrameSource:
    """Base class: iterate to get :class:`~aerotrack.types.Frame` objects in order.

    Attributes
    ----------
    path : Path
    fps : float
        Frames per second (given, read from the container, or 30 for image folders).
    size : (int, int)
        (width, height) in pixels.
    count : int or None
        Number of frames when known in advance (an estimate for some video containers).
    """

    path: Path
    fps: float
    size: tuple[int, int]
    count: int | None

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self, start: int = 1, stop: int | None = None, stride: int = 1) -> Iterator[Frame]:
        """Frames ``start, start+stride, ...`` up to and including ``stop`` (1-based)."""
        raise NotImplementedError

    def __len__(self) -> int:
        return int(self.count or 0)


class _Failed:
    """An exception raised while reading ahead, handed to the consumer."""

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


_END = object()


def read_ahead(frames: Iterator[Frame], depth: int = 2) -> Iterator[Frame]:
    """The frames of ``frames``, in order, read by a background thread up to ``depth`` frames
    ahead of the consumer.

    Decoding (8 ms per 1920x1080 H.264 frame, a few per JPEG image) then runs while the
    pipeline works on the previous frame: OpenCV's decoders and image readers release the GIL, so
    it takes the second core that the pipeline's single-threaded stages leave idle. The frames
    are the same objects the source yields; memory grows by ``depth`` frames. An exception of the
    source is raised to the consumer at the frame where it happened; when the consumer stops
    early (``break``, an interruption) the thread stops and closes the source.
    """
    q: queue.Queue = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for frame in frames:
                if not put(frame):
                    break
            else:
                put(_END)
        except BaseException as exc:  # noqa: BLE001 - the consumer raises it
            put(_Failed(exc))
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=work, name="aerotrack-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            try:
                item = q.get(timeout=0.5)
            except queue.Empty:
                if not thread.is_alive() and q.empty():
                    return
                continue
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.exc
            yield item
    finally:
        stop.set()
        thread.join(timeout=5.0)


def _check_fps(fps: float | None, label: str) -> float | None:
    if fps is None:
        return None
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"--fps {fps}: must be a positive number (for {label})")
    return float(fps)


_CV_LINKS: dict[str, str] = {}
_CV_LINK_DIR: list[str] = []
_CV_LINK_LOCK = threading.Lock()  # (threads of a dask worker open files at once)


def cv_path(path) -> str:
    """The name OpenCV is given for ``path``.

    OpenCV takes its file names as UTF-8 text. A name that is not valid UTF-8 (a FAT card's or a
    Windows zip's Latin-1 name, which Python holds with surrogate escapes) crashed the process in
    ``cv2.VideoCapture`` and ``cv2.imread`` (a segfault, exit 139, no message; a probe, also
    killing a whole batch). Such a path is reached through a link with a plain name in a private
    temporary folder (removed at exit), keeping its suffix (OpenCV picks image decoders by it).
    """
    s = str(path)
    try:
        s.encode("utf-8")
        return s
    except UnicodeEncodeError:
        pass
    key = os.path.abspath(s)
    with _CV_LINK_LOCK:
        return _CV_LINKS.get(key) or _new_link(key, s)


def _new_link(key: str, s: str) -> str:
    """A link to ``key`` with a plain name (:func:`cv_path`; called under its lock)."""
    import atexit
    import shutil
    import tempfile

    if not _CV_LINK_DIR:
        _CV_LINK_DIR.append(tempfile.mkdtemp(prefix="aerotrack-names-"))
        atexit.register(shutil.rmtree, _CV_LINK_DIR[0], True)
    suffix = Path(s).suffix
    try:
        suffix.encode("utf-8")
    except UnicodeEncodeError:
        suffix = ""
    link = os.path.join(_CV_LINK_DIR[0], f"{len(_CV_LINKS)}{suffix}")
    try:
        os.symlink(key, link)
    except OSError as exc:
        shown = s.encode("utf-8", "backslashreplace").decode("ascii", "replace")
        raise InputError(f"{shown}: its name is not valid UTF-8, which OpenCV cannot open "
                         f"({exc.strerror}); rename it") from None
    _CV_LINKS[key] = link
    return link


class VideoSource(FrameSource):
    """A video file anything OpenCV/FFmpeg decodes."""

    def __init__(self, path: str | Path, fps: float | None = None, *,
                 by_name: bool = False) -> None:
        self.path = Path(path)
        fps = _check_fps(fps, str(self.path))
        cap = cv2.VideoCapture(cv_path(self.path))
        try:
            if not cap.isOpened():
                raise InputError(f"{self.path}: cannot open as a video (unknown format or corrupt)")
            ok, img = cap.read()
            if not ok or img is None:
                raise InputError(f"{self.path}: video has no decodable frames")
            native = cap.get(cv2.CAP_PROP_FPS)
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            cap.release()
        self.size = (img.shape[1], img.shape[0])
        self.fps = fps or (float(native) if native and math.isfinite(native) and native > 0
                           else DEFAULT_FOLDER_FPS)
        if fps is None and self.path.suffix.lower() in RAW_STREAM_SUFFIXES:
            logging.getLogger(__name__).warning(
                "%s: a raw video stream holds no frame rate; FFmpeg assumes %g frames/s (give "
                "--fps if it is another: speeds and times follow it)", self.path, self.fps)
        self.count = n if n > 0 else None

    def timing_irregularity(self, n: int = 90) -> tuple[float, float] | None:
        """(shortest, longest) interval in ms between the first ``n`` frames' timestamps when they
        differ by more than a third (a variable-frame-rate video, as phones and some drones
        write), else None. Frames are numbered in decoding order and timed at ``fps``: speeds
        then run fast or slow where the rate differs from the mean."""
        cap = cv2.VideoCapture(cv_path(self.path))
        try:
            stamps = []
            while len(stamps) < n and cap.grab():
                stamps.append(cap.get(cv2.CAP_PROP_POS_MSEC))
        finally:
            cap.release()
        d = np.diff(np.asarray(stamps, float))
        d = d[d > 0]
        if len(d) < 10:
            return None
        lo, hi = float(np.percentile(d, 5)), float(np.percentile(d, 95))
        return (lo, hi) if hi > 1.34 * lo else None

    def frames(self, start: int = 1, stop: int | None = None, stride: int = 1) -> Iterator[Frame]:
        """Frames ``start, start+stride, ...`` up to and including ``stop`` (1-based), the video
        sought to ``start``.

        OpenCV's FFmpeg backend seeks to the keyframe before the frame and decodes forward to it,
        counting frames by their timestamps: exact for constant-rate videos (checked frame by
        frame against decoding from the first frame on Santiago's H.264 video, MPEG-4 part 2 and
        MJPEG encodings of generated ones; ``tests/test_io.py``). When the backend cannot seek
        (the position it reports afterwards is not the one asked for) the video is decoded from
        its first frame instead. A video with irregular timestamps could still land on a wrong
        frame: a segment-parallel join then shows it as a large ``JoinReport.world_rms``, and
        an exact ``--resume`` finds that the frames it re-reads differ from the ones it saved
        and falls back to the checkpoints (:mod:`aerotrack.io.state`).
        """
        log = logging.getLogger(__name__)
        cap = cv2.VideoCapture(cv_path(self.path))
        try:
            index = self._seek(cap, start) if start > 1 else 0  # frames before the next read
            if index < 0:  # cannot seek: decode from the first frame
                cap.release()
                cap = cv2.VideoCapture(cv_path(self.path))
                index = 0
            sought, fails, t_last = index > 0, 0, None
            while True:
                ok = cap.grab()
                if not ok and sought:  # sought, then nothing decodes (an MPEG-TS): from frame 1
                    log.info("%s: nothing decodes after seeking to frame %d; decoding from the "
                             "first frame", self.path, start)
                    cap.release()
                    cap = cv2.VideoCapture(cv_path(self.path))
                    index, sought = 0, False
                    continue
                sought = False
                if not ok:
                    # a damaged stretch: FFmpeg's decoder fails on it, then goes on
                    fails += 1
                    if fails <= MAX_DECODE_RETRIES and (self.count is None or index < self.count):
                        continue
                    expected = min(stop or self.count or 0, self.count or 0)
                    if index < expected - max(2, expected // 100):  # counts are estimates
                        log.warning(
                            "%s: decoding stopped after frame %d of the %d its header announces "
                            "(truncated or corrupt video?)", self.path, index, self.count)
                    return
                t_now = cap.get(cv2.CAP_PROP_POS_MSEC)
                if fails and t_last is not None:  # frames lost in the damage keep their numbers
                    lost = int(round((t_now - t_last) * self.fps / 1000.0)) - 1
                    if lost > 0:
                        log.warning("%s: frames %d-%d could not be decoded (corrupt); skipped",
                                    self.path, index + 1, index + lost)
                        index += lost
                fails, t_last = 0, t_now
                index += 1
                if stop is not None and index > stop:
                    return
                if index < start or (index - start) % stride:
                    continue
                ok, img = cap.retrieve()
                if not ok or img is None:
                    return
                if img.ndim == 2:
                    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                yield Frame(index=index, image=img, time=(index - 1) / self.fps)
        finally:
            cap.release()

    def _seek(self, cap, start: int) -> int:
        """Put ``cap`` before frame ``start``; the number of frames before it (``start - 1``),
        or -1 when the backend could not seek there."""
        if (cap.isOpened() and cap.set(cv2.CAP_PROP_POS_FRAMES, start - 1)
                and round(cap.get(cv2.CAP_PROP_POS_FRAMES)) == start - 1):
            return start - 1
        logging.getLogger(__name__).info("%s: cannot seek to frame %d; decoding from the first "
                                         "frame", self.path, start)
        return -1


#: Elementary streams without a container: no frame rate is stored (FFmpeg says 25).
RAW_STREAM_SUFFIXES = (".h264", ".264", ".h265", ".265", ".hevc", ".mjpeg", ".mjpg")

#: Consecutive frames a video may fail to decode (a damaged stretch) before it is taken to end.
MAX_DECODE_RETRIES = 25

#: Images sampled across a folder of 16-bit or floating-point frames to fix their 8-bit mapping.
DEPTH_SAMPLE_FILES = 9
#: Percentiles of the sampled values mapped to 0 and 255.
DEPTH_PERCENTILES = (0.1, 99.9)


class ImageFolderSource(FrameSource):
    """A folder of images, frame n = n-th image file in natural order of names (``img2`` before
    ``img10``; zero-padded names sort as they read).

    Files whose suffix is not an image type are ignored, and hidden files too (macOS leaves a
    ``._DJI_0001.JPG`` beside each image it copies to a card). Two images of one name
    (``0001.jpg`` and ``0001.png``) are refused: which is the frame? An image that cannot be
    decoded after the first is skipped with a warning (the frames around it are tracked as
    across a ``--stride`` gap), not the end of a long run. Transparent pixels of images with an
    alpha channel are made black, as the fill of a stabilised video, which detection ignores. All images must have the size of the
    first one; a different size is an error naming the file. Grey and colour images of 8 bits
    are read as BGR. Frames of more bits (16-bit TIFF or PNG, as radiometric thermal cameras
    write them, often over a narrow band of a 14-bit range) or floating point are mapped to 8
    bits by one linear map for the whole folder (:attr:`depth_range`): the median over
    ``DEPTH_SAMPLE_FILES`` images spread across the folder of each image's 0.1 and 99.9
    percentiles go to 0 and 255 (an alpha channel is left out).
    Reading them as OpenCV does by default (the top 8 bits) leaves a 14-bit sensor a few grey
    levels, a blank frame; a per-frame stretch would change every pixel's value whenever a hot
    object enters, which the background would take for motion.
    """

    def __init__(self, path: str | Path, fps: float | None = None, *,
                 by_name: bool = False) -> None:
        self.path = Path(path)
        self.fps = _check_fps(fps, str(self.path)) or DEFAULT_FOLDER_FPS
        self.files = sorted(
            (p for p in self.path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
             and not p.name.startswith(".")),
            key=natural_key,
        )
        if not self.files:
            raise InputError(f"{self.path}: folder holds no image files")
        if fps is None and self.path.resolve() not in _ASSUMED_RATE:
            _ASSUMED_RATE.add(self.path.resolve())
            logging.getLogger(__name__).info(
                "%s: image files hold no frame rate; timed at %g frames/s (give --fps if it is "
                "another: speeds and every time-based setting follow it)", self.path, self.fps)
        stems: dict[tuple, Path] = {}
        for f in self.files:  # one name, two kinds (0001.jpg, 0001.png), or img3 beside img03
            key = tuple(t[:2] for t in natural_key(f.with_suffix("")))
            if key in stems:
                raise InputError(f"{self.path}: both {stems[key].name} and {f.name}: one "
                                 "image per frame expected (which comes first?)")
            stems[key] = f
        #: with ``by_name`` and files named by numbers only (a MOTChallenge sequence's 000001.jpg):
        #: frame n is the file numbered n, None where none is (a missing image: skipped, as an
        #: undecodable one); else frame n is the n-th file
        self._slots: list[Path | None] | None = None
        nums = [int(f.stem) if f.stem.isdigit() else 0 for f in self.files]
        if by_name and min(nums) >= 1 and len(set(nums)) == len(nums):
            self._slots = [None] * max(nums)
            for n, f in zip(nums, self.files):
                self._slots[n - 1] = f
            missing = [i + 1 for i, f in enumerate(self._slots) if f is None]
            if missing:
                logging.getLogger(__name__).warning(
                    "%s: no image for %d frame%s (first: frame %d): frames are numbered by the "
                    "files' names, as the sequence's annotations are, and those are skipped",
                    self.path, len(missing), "s" * (len(missing) != 1), missing[0])
        else:
            _warn_numbering_gaps(self.path, self.files)
        #: (low, high) values mapped to 0 and 255 for frames of more than 8 bits, else None.
        self.depth_range: tuple[float, float] | None = None
        #: Frames whose image could not be decoded (skipped with a warning), for summary.json.
        self.skipped_frames: set[int] = set()
        self._warned: set[Path] = set()  # truncated JPEGs already reported
        raw = self._decode(self.files[0])
        #: whether images carry an alpha channel (transparent pixels read black)
        self.alpha = False
        if self.files[0].suffix.lower() in (".png", ".tif", ".tiff", ".webp"):
            full = cv2.imread(cv_path(self.files[0]), cv2.IMREAD_UNCHANGED)
            self.alpha = full is not None and full.ndim == 3 and full.shape[2] == 4
        if raw.dtype != np.uint8:
            self.depth_range = self._depth_range(raw)
            logging.getLogger(__name__).info(
                "%s: %s images mapped to 8 bits linearly from %g-%g (one map for every frame)",
                self.path, raw.dtype, *self.depth_range)
        first = self._read(self.files[0])
        self.size = (first.shape[1], first.shape[0])
        self.count = len(self._slots) if self._slots is not None else len(self.files)

    def _decode(self, p: Path) -> np.ndarray:
        flags = cv2.IMREAD_UNCHANGED if getattr(self, "alpha", False) else \
            cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR
        img = cv2.imread(cv_path(p), flags)
        if img is None:
            raise UnreadableImage(f"{p}: cannot decode image")
        return img

    def _depth_range(self, first: np.ndarray) -> tuple[float, float]:
        """The folder's (low, high) percentiles over images spread across it (see the class)."""
        n = len(self.files)
        picks = sorted({round(k * (n - 1) / max(DEPTH_SAMPLE_FILES - 1, 1))
                        for k in range(DEPTH_SAMPLE_FILES)})
        ranges = []
        for k in picks:
            try:
                img = first if k == 0 else self._decode(self.files[k])
            except UnreadableImage:  # skipped when read as a frame too; the others decide
                continue
            if img.dtype == np.uint8:  # an 8-bit file among deeper ones says nothing of them
                continue
            if img.ndim == 3 and img.shape[2] == 4:  # alpha is opacity, not a sensor value
                img = img[:, :, :3]
            v = np.asarray(img, np.float64)[::4, ::4].ravel()
            v = v[np.isfinite(v)]
            if len(v):
                ranges.append(np.percentile(v, DEPTH_PERCENTILES))
        if not ranges:
            raise InputError(f"{self.files[0]}: image holds no finite values")
        # the median image's percentiles: one odd frame (a thermal camera's flat-field
        # correction jump) among the samples does not move the map of every other frame
        lo, hi = (float(x) for x in np.median(np.array(ranges), axis=0))
        return lo, (hi if hi > lo else lo + 1.0)

    def _read(self, p: Path) -> np.ndarray:
        try:
            empty = p.stat().st_size == 0
        except OSError as exc:
            raise UnreadableImage(f"{p}: cannot read ({exc.strerror or exc})") from None
        if empty:
            raise UnreadableImage(f"{p}: empty file (0 bytes)")
        truncated = p.suffix.lower() in (".jpg", ".jpeg") and not jpeg_complete(p)
        if truncated:
            if p not in self._warned:
                self._warned.add(p)
                logging.getLogger(__name__).warning(
                    "%s: truncated JPEG (no end-of-image marker): what is missing decodes grey, "
                    "and that frame's detections and registration suffer", p)
            with stderr_silenced():  # libjpeg's own nameless "Premature end of JPEG file"
                return self._read_decoded(p)
        return self._read_decoded(p)

    def _read_decoded(self, p: Path) -> np.ndarray:
        if self.depth_range is None and not self.alpha:
            img = cv2.imread(cv_path(p), cv2.IMREAD_COLOR)
            if img is None:
                raise UnreadableImage(f"{p}: cannot decode image")
            return img
        if self.depth_range is None:  # 8 bits with alpha
            img = cv2.imread(cv_path(p), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise UnreadableImage(f"{p}: cannot decode image")
            return _opaque_bgr(img)
        img = self._decode(p)
        if img.dtype == np.uint8:  # an 8-bit file among deeper ones: as it is
            img8 = img
        else:
            lo, hi = self.depth_range
            f = np.nan_to_num(np.asarray(img, np.float32), nan=lo, posinf=hi, neginf=lo)
            f = (f - np.float32(lo)) * np.float32(255.0 / (hi - lo)) + np.float32(0.5)
            img8 = np.clip(f, 0, 255).astype(np.uint8)
        return _opaque_bgr(img8)

    def frames(self, start: int = 1, stop: int | None = None, stride: int = 1) -> Iterator[Frame]:
        last = self.count if stop is None else min(stop, self.count)
        for index in range(start, last + 1, stride):
            p = self.files[index - 1] if self._slots is None else self._slots[index - 1]
            if p is None:  # no file of this number (said once when the folder was opened)
                self.skipped_frames.add(index)
                continue
            try:
                img = self._read(p)
            except UnreadableImage as exc:  # one bad file must not end a long run
                self.skipped_frames.add(index)
                if p not in _SKIPPED:  # once per file, however often the folder is read
                    _SKIPPED.add(p)
                    logging.getLogger(__name__).warning("%s; frame %d skipped", exc, index)
                continue
            if (img.shape[1], img.shape[0]) != self.size:
                raise InputError(
                    f"{p}: image is {img.shape[1]}x{img.shape[0]}, expected "
                    f"{self.size[0]}x{self.size[1]} like the first image"
                )
            yield Frame(index=index, image=img, time=(index - 1) / self.fps)


#: Unreadable image files already reported (``render`` and ``report`` read a folder twice).
_SKIPPED: set[Path] = set()


class UnreadableImage(InputError):
    """An image file of a folder that cannot be decoded (empty, corrupt)."""


_GAPS_WARNED: set[Path] = set()


def _warn_numbering_gaps(folder: Path, files: list[Path]) -> None:
    """Warn when the files' numbers skip (``000049.png``, ``000051.png``): frame n is the n-th
    file, so every frame after a missing file is numbered lower than its name, and ground truth
    numbered by the names is off by one from there (a probe: HOTA 0.780 -> 0.730, silently)."""
    import re

    if folder.resolve() in _GAPS_WARNED:  # once per folder in a process (it is opened again)
        return
    _GAPS_WARNED.add(folder.resolve())
    nums = []
    for f in files:
        m = re.search(r"(\d+)\D*$", f.stem)
        if m is not None:  # (one file without a number, frame_final.jpg, turned the check off)
            nums.append(int(m.group(1)))
    if len(nums) < 0.8 * len(files):  # not a numbered sequence
        return
    steps = np.diff(nums)
    if len(steps) < 2 or len(set(steps.tolist())) == 1:  # one spacing (every 5th file kept) is a
        return                                            # numbering, not a gap
    usual = int(np.median(steps))
    gaps = [(nums[i], nums[i + 1]) for i in np.flatnonzero(steps > usual)]
    if not gaps or usual < 1:
        return
    shown = ", ".join(f"{a}-{b}" for a, b in gaps[:3]) + (", ..." if len(gaps) > 3 else "")
    missing = sum((b - a) // usual - 1 for a, b in gaps)
    logging.getLogger(__name__).warning(
        "%s: the file numbers skip %d time%s (between %s; about %d file%s missing): frames are "
        "numbered by the files' order (frame n is the n-th file), so after a gap frame numbers "
        "are lower than the names', and ground truth numbered by the names no longer lines up",
        folder, len(gaps), "s" * (len(gaps) != 1), shown, missing, "s" * (missing != 1))


def natural_key(p: Path) -> tuple:
    """Sort key reading digit runs as numbers: ``img2`` < ``img10`` (``0002`` < ``0010`` too)."""
    parts = re.split(r"(\d+)", p.name.lower())
    return tuple((0, int(t), t) if t.isdigit() else (1, 0, t) for t in parts)


def _opaque_bgr(img: np.ndarray) -> np.ndarray:
    """8-bit BGR from grey, BGR or BGRA; transparent pixels (alpha 0) black."""
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        bgr = np.ascontiguousarray(img[:, :, :3])
        bgr[img[:, :, 3] == 0] = 0
        return bgr
    return np.ascontiguousarray(img[:, :, :3])


_STDERR_LOCK = threading.Lock()


@contextlib.contextmanager
def stderr_silenced() -> Iterator[None]:
    """The process's standard error (file descriptor 2) sent to the null device for the block.

    libjpeg reports a truncated file by printing to descriptor 2 itself, below Python, and
    without the file's name; the reader has already named the file in a warning, so the
    decoder's line is only noise, and it ignored ``-q``. Whatever another thread writes to
    standard error during the decode (a few milliseconds) is lost too; only truncated files are
    decoded this way.
    """
    fd = 2  # C's stderr, whatever sys.stderr is
    with _STDERR_LOCK:
        try:
            saved = os.dup(fd)
        except OSError:  # no descriptor 2 (a daemon): nothing to silence
            yield
            return
        try:
            if sys.stderr is not None:
                sys.stderr.flush()
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, fd)
            finally:
                os.close(null)
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)


def jpeg_complete(path: Path) -> bool:
    """Whether a JPEG file ends with its end-of-image marker (FF D9; a few padding bytes after
    it are allowed). libjpeg decodes a truncated file without an error, filling what is missing
    with grey, and says so only on the process's standard error, without the file's name."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 64))
            tail = fh.read()
    except OSError:
        return True  # the decoder reports unreadable files
    return b"\xff\xd9" in tail


#: URL schemes of network streams FFmpeg reads (a drone's live feed, a ground station's relay).
STREAM_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "udp", "tcp", "srt", "rtp")

#: Reads that fail in a row before a stream counts as ended (a network hiccup loses a frame or
#: two; FFmpeg reconnects inside its own timeouts).
STREAM_MAX_FAILS = 5

#: Seconds behind a live feed at which a run says so (then again at each doubling).
STREAM_LAG_WARN_S = 10.0

#: Longest believable frame rate a stream announces (FFmpeg reports 90000 for some RTP streams).
STREAM_MAX_FPS = 240.0


def is_stream_url(path) -> bool:
    """Whether ``path`` is a network stream's URL (``rtsp://...``, ``udp://...``; see
    :data:`STREAM_SCHEMES`), not a file name."""
    if not isinstance(path, str):
        return False
    scheme, sep, _ = path.partition("://")
    return bool(sep) and scheme.lower() in STREAM_SCHEMES


class StreamSource(FrameSource):
    """A live network stream (RTSP, RTMP, SRT, UDP, HTTP): read once, in order, until it ends.

    Frames are numbered as they arrive, from 1 (the first frame read when the stream was
    opened). A stream cannot be sought, so ``start`` skips frames by reading them, and a stream
    cannot be read twice: frames before the current one are gone (``--resume`` and segment-
    parallel runs need a file). The length is unknown (``count`` None); the stream ends when
    the sender closes it or :data:`STREAM_MAX_FAILS` reads fail in a row. When processing is
    slower than the feed, FFmpeg buffers it and the run falls behind live (use ``--stride``).
    """

    def __init__(self, url: str, fps: float | None = None) -> None:
        self.path = url  # type: ignore[assignment]  # (a URL: there is no file)
        fps = _check_fps(fps, url)
        cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            raise InputError(f"{url}: cannot open the stream ({why_stream_fails(url)})")
        if _fourcc(cap) == TEXT_CODEC:  # FFmpeg's tty demuxer draws text (a web page) as frames
            cap.release()
            raise InputError(f"{url}: is text (a web page?), not a video stream")
        ok, img = cap.read()
        if not ok or img is None:
            cap.release()
            raise InputError(f"{url}: the stream opened but sent no decodable frame")
        native = cap.get(cv2.CAP_PROP_FPS)
        self._cap, self._first = cap, img
        self.size = (img.shape[1], img.shape[0])
        self.count = None
        if fps is not None:
            self.fps = fps
        elif native and math.isfinite(native) and 0 < native <= STREAM_MAX_FPS:
            self.fps = float(native)
        else:
            self.fps = DEFAULT_FOLDER_FPS
            logging.getLogger(__name__).warning(
                "%s: the stream names no believable frame rate (%g); timed at %g frames/s (give "
                "--fps: speeds and every time-based setting follow it)", url, native, self.fps)

    def frames(self, start: int = 1, stop: int | None = None, stride: int = 1) -> Iterator[Frame]:
        """Frames ``start, start+stride, ...`` up to ``stop`` as they arrive. The first call
        goes on from the frame read when the stream was opened; a later call opens the stream
        again and numbers what arrives from 1 again (a live feed has moved on meanwhile)."""
        cap, img = self._cap, self._first
        self._cap = self._first = None
        if cap is None:
            cap = cv2.VideoCapture(self.path, cv2.CAP_FFMPEG)
            ok, img = cap.read() if cap.isOpened() else (False, None)
            if not ok:
                cap.release()
                return
        log = logging.getLogger(__name__)
        t0, behind = time.monotonic(), STREAM_LAG_WARN_S
        try:
            index, fails = 1, 0
            while True:
                if stop is not None and index > stop:
                    return
                if index >= start and (index - start) % stride == 0:
                    if img.ndim == 2:
                        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                    yield Frame(index=index, image=img, time=(index - 1) / self.fps)
                if stop is not None and index >= stop:
                    return
                while True:
                    ok, img = cap.read()
                    if ok and img is not None:
                        fails = 0
                        break
                    fails += 1
                    if fails >= STREAM_MAX_FAILS:
                        log.warning("%s: the stream ended (or was lost) after frame %d",
                                    self.path, index)
                        return
                index += 1
                # behind live: the feed's time against the time spent reading it (a sender
                # throttled by the network's back-pressure lets the delay grow unseen)
                lag = (time.monotonic() - t0) - (index - 1) / self.fps
                if lag > behind:
                    log.warning("%s: %.0f s behind real time at frame %d (processing at %.1f "
                                "of its %g frames/s; if the feed is live, --stride N or smaller "
                                "frames keep up)",
                                self.path, lag, index, (index - 1) / (time.monotonic() - t0),
                                self.fps)
                    behind = 2 * lag
        finally:
            cap.release()

    def close(self) -> None:
        """Release the stream if no frame was read from it."""
        if self._cap is not None:
            self._cap.release()
            self._cap = self._first = None


#: The codec FFmpeg reports for text it renders as frames (its tty demuxer).
TEXT_CODEC = "ansi"


def _fourcc(cap) -> str:
    """The four-character code of an open capture's codec ('' when it names none)."""
    code = int(cap.get(cv2.CAP_PROP_FOURCC))
    return code.to_bytes(4, "little").decode("latin-1").strip("\0 ") if code > 0 else ""


#: Default ports of the stream schemes that run over TCP (what a URL without a port reaches).
TCP_STREAM_PORTS = {"rtsp": 554, "rtsps": 322, "rtmp": 1935, "rtmps": 443, "http": 80,
                    "https": 443, "tcp": None}

#: How long :func:`why_stream_fails` waits for a host to answer.
STREAM_PROBE_TIMEOUT_S = 3.0


def why_stream_fails(url: str) -> str:
    """Why FFmpeg could not open ``url``, as far as one connection attempt can tell: the host is
    unknown, refuses or does not answer; an HTTP server answers with an error status; or
    something answers but FFmpeg found no video there. UDP, SRT and RTP have no connection to
    test (a sender that has not started looks like one that does not exist)."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    try:
        host, port = parts.hostname, parts.port
    except ValueError:  # a port that is not a number
        return "its port is not a number"
    if scheme not in TCP_STREAM_PORTS:
        return (f"nothing arrived: is the sender running and sending to this address? "
                f"{scheme.upper()} has no connection to test")
    port = port or TCP_STREAM_PORTS[scheme]
    if not host:
        return "the URL names no host"
    if port is None:
        return f"the URL names no port ({scheme}:// needs one)"
    if scheme in ("http", "https"):
        import urllib.error
        import urllib.request

        request = urllib.request.Request(url, headers={"Range": "bytes=0-0"})
        try:
            with urllib.request.urlopen(request, timeout=STREAM_PROBE_TIMEOUT_S) as reply:
                kind = reply.headers.get_content_type()
        except urllib.error.HTTPError as exc:
            return f"the server answers HTTP {exc.code} {exc.reason}"
        except (urllib.error.URLError, OSError) as exc:
            return _socket_trouble(getattr(exc, "reason", exc), host, port)
        return f"the server answers, but with no video FFmpeg can read: it sends {kind}"
    try:
        with socket.create_connection((host, port), timeout=STREAM_PROBE_TIMEOUT_S):
            pass
    except OSError as exc:
        return _socket_trouble(exc, host, port)
    return (f"{host}:{port} answers, but FFmpeg could not read a stream there (a wrong path or "
            "stream name, credentials, or a format it cannot read)")


def _socket_trouble(exc, host: str, port: int) -> str:
    """One socket error as words."""
    import socket

    if isinstance(exc, socket.gaierror):
        return f"the host {host} is not known"
    if isinstance(exc, ConnectionRefusedError):
        return f"{host}:{port} refuses the connection: nothing listens there"
    if isinstance(exc, TimeoutError | socket.timeout):
        return f"{host}:{port} does not answer within {STREAM_PROBE_TIMEOUT_S:g} s"
    return f"{host}:{port}: {getattr(exc, 'strerror', None) or exc}"


#: A MOTChallenge sequence folder's description: ``SEQ/seqinfo.ini`` naming its image folder
#: (``imDir``, usually ``img1``) and ``frameRate``.
SEQINFO = "seqinfo.ini"


def mot_sequence(folder: str | Path) -> tuple[Path, float | None] | None:
    """A MOTChallenge sequence folder (``SEQ/seqinfo.ini``, ``SEQ/img1/``): ``(image folder,
    frame rate or None)``; None for any other folder. The ``[Sequence]`` section's ``imDir``
    (default ``img1``) names the images and ``frameRate`` their rate; an unreadable file, an
    ``imDir`` outside the folder or a rate that is not a positive number is an
    :class:`InputError` naming the file."""
    import configparser

    folder = Path(folder)
    ini = folder / SEQINFO
    if not ini.is_file():
        return None
    cp = configparser.ConfigParser(interpolation=None)
    try:
        cp.read(ini, encoding="utf-8-sig")  # (a BOM, as Windows editors save)
        section = next((n for n in cp.sections() if n.lower() == "sequence"), None)
        if section is None:  # some other program's file: a plain folder
            return None
        given = cp.get(section, "imDir", fallback="").strip().rstrip("/\\")
        rate = cp.get(section, "frameRate", fallback="").strip()
    except (configparser.Error, UnicodeDecodeError) as exc:
        raise InputError(f"{ini}: unreadable ({type(exc).__name__}): expected a MOTChallenge "
                         "[Sequence] section with imDir and frameRate") from None
    im_dir = given or "img1"
    if Path(im_dir).is_absolute() or ".." in Path(im_dir).parts:  # (a link inside is fine)
        raise InputError(f"{ini}: imDir {im_dir!r} is not a folder inside {folder}")
    if not given and not (folder / im_dir).is_dir() and any(
            q.suffix.lower() in IMAGE_SUFFIXES for q in folder.iterdir()):
        im_dir = "."  # a folder of images beside a seqinfo.ini that names no imDir
    fps = None
    if rate:
        try:
            fps = float(rate)
        except ValueError:
            fps = math.nan
        if not (math.isfinite(fps) and fps > 0):
            raise InputError(f"{ini}: frameRate {rate!r} is not a positive number")
    return folder / im_dir, fps


def open_source(path: str | Path, fps: float | None = None) -> FrameSource:
    """Open a video file, an image folder or a network stream (a URL, :data:`STREAM_SCHEMES`).

    A MOTChallenge sequence folder (:func:`mot_sequence`) is read from its image folder, at its
    ``frameRate`` unless ``fps`` is given.

    Raises
    ------
    InputError
        Missing path, unreadable video, empty folder, or a bad ``fps``.
    """
    if is_stream_url(path):
        return StreamSource(str(path), fps)
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if p.is_dir():
        seq = mot_sequence(p)
        if seq is not None:
            images, rate = seq
            if not images.is_dir():
                raise InputError(f"{p}: its {SEQINFO} names the image folder {images.name}/, "
                                 "which is not there")
            logging.getLogger(__name__).info(
                "%s: a MOTChallenge sequence: frames from %s/%s", p, images.name,
                f", {rate:g} frames/s ({SEQINFO})" if fps is None and rate else "")
            return ImageFolderSource(images, fps if fps is not None else rate, by_name=True)
        return ImageFolderSource(p, fps)
    if p.stat().st_size == 0:
        raise InputError(f"{p}: file is empty")
    if p.suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(f"{p}: is a single image; give a video file or a folder of images")
    if looks_like_text(p):  # FFmpeg would draw a text file as frames of text (its tty demuxer)
        raise InputError(f"{p}: is a text file, not a video (detections go with --detections "
                         "FILE)")
    return VideoSource(p, fps)


def looks_like_text(path: Path, n: int = 4096) -> bool:
    """Whether a file's first ``n`` bytes are text (UTF-8, no NUL byte): every video container
    holds binary headers within its first bytes."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(n)
    except OSError:
        return False
    if not head or b"\x00" in head:
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not only a character cut at the end of the sample
            return False
    return True
