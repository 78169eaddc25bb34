"""The working state of the stages, saved when a run is interrupted, so ``--resume`` is exact.

Periodic checkpoints (:mod:`aerotrack.io.checkpoint`) keep what the stages *finished*
(registrations, final detections). What they are still working on -- the registrar's keyframe and
chain, the detector's window of registered frames, its background, held vehicles and frames not yet
final -- is not in them, so a run resumed from checkpoints alone restarts registration and
detection a little before where they stopped and can decide a few frames differently from an
uninterrupted run. On Ctrl-C or SIGTERM the pipeline stops *between* two frames and also saves that
working state here (``DIR/.partial/state.npz``); ``--resume`` puts it back and continues with the
next frame, which gives exactly the uninterrupted run's results.

The state is saved generically, attribute by attribute, so a stage that gains state is covered
without code here: numbers, strings, numpy arrays and scalars, ``numpy.random.Generator``s,
lists, tuples, dicts (``OrderedDict``, ``Counter``), deques, sets, and objects of aerotrack's own
classes (rebuilt without calling their constructor). Nothing is unpickled: arrays go into the
``.npz`` (loaded with ``allow_pickle=False``), the structure is JSON, and a class is only looked up
inside the ``aerotrack`` package. Attributes still holding what the constructor gave them (the
config, the map and its grey image) are not saved: the resumed run's constructor, given the same
inputs (``--resume`` checks), makes them again. A value of any other type makes :func:`save_state`
raise :class:`StateNotSaved`; the run then resumes from its checkpoints alone.

Frames are not saved, they are read again. Most of the working state is the detector's frames
not yet final (half a background window of full frames, ``detection.window_s * fps / 2``) and
their model-resolution copies, all of which the input gives again: the pipeline passes the frames
the stages still hold (:class:`Rereadable`), and an array equal to one of them, or to what a stage
derives from one (``MovingObjectDetector.model_image``), byte for byte, is saved as a reference
(frame, kind, CRC-32); so is what a stage keeps of a frame no stage holds whole any more, made
by one of those functions (:attr:`Rereadable.kept`: the stop follower's grey frames of the last
few seconds). ``--resume`` reads those frames again (a video is sought to the first,
:meth:`~aerotrack.io.frames.VideoSource.frames`), makes the derived arrays again and checks every
CRC: an input that now gives other pixels (a replaced file, a video whose seeking lands elsewhere)
raises :class:`FramesChanged`, and the run resumes from its checkpoints alone, with a warning,
rather than continue from a state it cannot reproduce. What remains in the file (compressed) is
model-resolution samples of frames already final, the background and the registrar's keyframe.
Measured on generated scenes at 30 frames/s: 54.8 MB before (full frames, uncompressed) and
3.7 MB now at 640x480 (interrupted at frame 1500 of an MPEG-4 video; 2.0 MB of it association's
window, below), 350.8 MB and 13.2 MB at 1920x1080 (at frame 100); saving takes 0.6-0.7 CPU s at
1920x1080 either way (CRCs and compression instead of writing the frames), and re-reading the 45
frames on resume 0.05 CPU s at 640x480 (seeking to frame 1456; decoding frames 1 to 1500 took
0.77 CPU s).
It is written once, on interruption (periodic checkpoints do not write it), and is stale (ignored)
once a later checkpoint exists.

Local association is saved too (its window, random generator, tracklets being built), with the
finished tracklets spilled so far linked into ``DIR/.partial/state-tracklets/``: ``--resume``
then takes them back instead of replaying association over every checkpointed frame: restoring
after 1500 frames at 640x480 took 4.0 CPU s with the replay and 0.35 CPU s without (association
runs at a few hundred frames per CPU second: replaying an hour of video would take minutes).
Without them (the folder removed, or association holding a value the codec cannot write)
association is replayed, with the same result. The stop follower (``association.follow_stopped``)
is saved with association, its state referring to association's tracks; when association is
replayed, following starts again.
"""

from __future__ import annotations

import importlib
import json
import shutil
import zipfile
import zlib
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .output import atomic_write

STATE_FILE = "state.npz"
#: Beside the state: the finished tracklets spilled when it was saved (hard links of the spill
#: files), taken back by the resumed run instead of replaying association.
STATE_TRACKLETS = "state-tracklets"
_VERSION = 2  # 2: frame references; a version-1 file is read as before


#: What reading a damaged ``.npz`` raises (a truncated or altered zip, a missing member).
UNREADABLE = (OSError, ValueError, KeyError, TypeError, AttributeError, EOFError,
              zipfile.BadZipFile)


def _unreadable(path: Path, exc: BaseException) -> InputError:
    return InputError(f"--resume: stage state {path} is unreadable ({exc or type(exc).__name__}); "
                      "delete it to resume from the checkpoints alone")


class StateNotSaved(TypeError):
    """A stage holds a value the state codec cannot write (the message names where)."""


def _immutable(value: Any) -> bool:
    if value is None or type(value) in (bool, int, float, str, bytes, frozenset):
        return True
    if isinstance(value, np.generic):
        return True
    if type(value) is tuple:
        return all(_immutable(v) for v in value)
    params = getattr(type(value), "__dataclass_params__", None)
    return bool(params is not None and params.frozen)


def _fingerprint(value: Any) -> tuple[int, int | None] | None:
    """(identity, CRC of the bytes for an array) of a value that can only change by being
    replaced (an array is checked byte by byte); None for a mutable container or object, which
    may have changed in place and is always saved."""
    if isinstance(value, np.ndarray) and value.dtype != object:
        return id(value), zlib.crc32(np.ascontiguousarray(value).view(np.uint8).reshape(-1))
    if _immutable(value):
        return id(value), None
    return None


def as_built(obj: object) -> dict[str, tuple[int, int | None]]:
    """Fingerprints of ``obj``'s attributes right after its constructor; pass them to
    :func:`save_state` so that what the constructor made (and nothing changed since: the config,
    an array derived from the map) is not saved. Mutable containers and objects are always
    saved, since they may have changed in place."""
    out = {}
    for k, v in vars(obj).items():
        f = _fingerprint(v)
        if f is not None:
            out[k] = f
    return out


def _crc(a: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).reshape(-1))


@dataclass(frozen=True)
class Rereadable:
    """Arrays a resumed run can make again from its input, so state.npz need not hold them.

    Parameters
    ----------
    images : mapping of int -> ndarray
        Frame index (1-based) -> the image the stages were given for it (after undistortion).
    derive : mapping of str -> callable
        Name -> a function of one image making an array the stages keep beside it (the
        detector's model-resolution copy: ``MovingObjectDetector.model_image``). It must be
        deterministic: the resumed run calls it again on the re-read image.
    kept : mapping of int -> mapping of str -> ndarray
        Frame index -> name -> what ``derive[name]`` made of that frame's image, for frames no
        stage holds whole any more (the stop follower's grey frames,
        ``StopFollower.kept``): saved as references too, their frames read again on resume.
    """

    images: Mapping[int, np.ndarray]
    derive: Mapping[str, Callable[[np.ndarray], np.ndarray]] = field(default_factory=dict)
    kept: Mapping[int, Mapping[str, np.ndarray]] = field(default_factory=dict)

    def kinds(self) -> dict[str, Callable[[np.ndarray], np.ndarray]]:
        return {"image": lambda img: img, **self.derive}

    def lookup(self) -> dict[tuple, tuple[int, str]]:
        """(shape, dtype, CRC-32) -> (frame, kind) of every image and derived array."""
        out = {}
        for index, img in self.images.items():
            for kind, fn in self.kinds().items():
                a = fn(img)
                out.setdefault((a.shape, a.dtype.str, _crc(a)), (int(index), kind))
        for index, arrays in self.kept.items():
            for kind, a in arrays.items():
                out.setdefault((a.shape, a.dtype.str, _crc(a)), (int(index), kind))
        return out


class FramesChanged(ValueError):
    """The frames re-read on resume are not the ones the state was saved with."""


class _Encoder:
    def __init__(self, frames: Rereadable | None = None) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.memo: dict[int, int] = {}  # id -> node number: shared objects stay shared
        self.keep: list[Any] = []  # holds encoded objects alive, so their ids are not reused
        self.lookup = frames.lookup() if frames is not None else {}
        self.shapes = {(k[0], k[1]) for k in self.lookup}
        self.referenced = 0  # bytes left out as frame references

    def _array(self, a: np.ndarray) -> str:
        name = f"a{len(self.arrays)}"
        self.arrays[name] = a
        return name

    def encode(self, v: Any, where: str) -> Any:
        if v is None or isinstance(v, (bool, int, float, str)):
            if type(v) not in (type(None), bool, int, float, str):  # IntEnum, str subclasses...
                raise StateNotSaved(f"{where}: {type(v).__qualname__} is not saved")
            return {"t": "v", "v": v}
        if isinstance(v, np.generic):
            return {"t": "np", "a": self._array(np.asarray(v))}
        if id(v) in self.memo:
            return {"t": "ref", "n": self.memo[id(v)]}
        n = len(self.memo)
        self.memo[id(v)] = n
        self.keep.append(v)
        node = self._encode_new(v, where)
        node["n"] = n
        return node

    def _encode_new(self, v: Any, where: str) -> dict:
        if isinstance(v, np.ndarray):
            if v.dtype == object:
                raise StateNotSaved(f"{where}: an object array is not saved")
            if (v.shape, v.dtype.str) in self.shapes:
                crc = _crc(v)
                ref = self.lookup.get((v.shape, v.dtype.str, crc))
                if ref is not None:
                    self.referenced += v.nbytes
                    return {"t": "frame", "f": ref[0], "k": ref[1], "crc": crc}
            return {"t": "nd", "a": self._array(v)}
        if isinstance(v, np.random.Generator):
            return {"t": "rng", "bit": type(v.bit_generator).__name__,
                    "state": v.bit_generator.state}
        if type(v) in (list, tuple, set, frozenset):
            items = sorted(v, key=repr) if isinstance(v, (set, frozenset)) else v
            return {"t": type(v).__name__,
                    "v": [self.encode(x, f"{where}[{i}]") for i, x in enumerate(items)]}
        if type(v) is deque:
            return {"t": "deque", "maxlen": v.maxlen,
                    "v": [self.encode(x, f"{where}[{i}]") for i, x in enumerate(v)]}
        if type(v) in (dict, OrderedDict, Counter):
            return {"t": type(v).__name__,
                    "k": [self.encode(k, f"{where} key") for k in v],
                    "v": [self.encode(x, f"{where}[{k!r}]") for k, x in v.items()]}
        cls = type(v)
        if cls.__module__.split(".")[0] == "aerotrack" and hasattr(v, "__dict__") \
                and not hasattr(cls, "__slots__"):
            return {"t": "obj", "m": cls.__module__, "c": cls.__qualname__,
                    "d": {k: self.encode(x, f"{where}.{k}") for k, x in vars(v).items()}}
        if cls.__module__.split(".")[0] == "aerotrack" and not hasattr(v, "__dict__"):
            slots = _slots(cls)
            if slots:  # a slotted class: its slots are its attributes (unset ones stay unset)
                return {"t": "obj", "m": cls.__module__, "c": cls.__qualname__,
                        "d": {k: self.encode(getattr(v, k), f"{where}.{k}") for k in slots
                              if hasattr(v, k)}}
        raise StateNotSaved(f"{where}: a {cls.__module__}.{cls.__qualname__} is not saved")


class _Decoder:
    def __init__(self, arrays, frames: Mapping[int, np.ndarray] | None = None,
                 derive: Mapping[str, Callable[[np.ndarray], np.ndarray]] | None = None) -> None:
        self.arrays = arrays
        self.memo: dict[int, Any] = {}
        self.frames = frames or {}
        self.kinds = Rereadable({}, derive or {}).kinds()
        self.given: set[tuple[int, str]] = set()

    def decode(self, node: dict) -> Any:
        t = node["t"]
        if t == "v":
            return node["v"]
        if t == "np":
            return self.arrays[node["a"]][()]
        if t == "ref":
            return self.memo[node["n"]]
        n = node["n"]
        if t == "nd":
            self.memo[n] = out = np.array(self.arrays[node["a"]])
            return out
        if t == "frame":
            img, fn = self.frames.get(node["f"]), self.kinds.get(node["k"])
            if img is None or fn is None:
                raise FramesChanged(f"frame {node['f']} ({node['k']}) was not re-read")
            out = fn(img)
            key = (node["f"], node["k"])
            if key in self.given or out is img and node["k"] != "image":
                out = out.copy()  # stages may change arrays in place: no two share one
            self.given.add(key)
            if _crc(out) != node["crc"]:
                raise FramesChanged(f"frame {node['f']} re-read from the input differs from "
                                    "the one the state was saved with")
            self.memo[n] = out
            return out
        if t == "rng":
            bit = getattr(np.random, node["bit"], None)
            if not (isinstance(bit, type) and issubclass(bit, np.random.BitGenerator)):
                raise ValueError(f"unknown bit generator {node['bit']!r}")
            gen = np.random.Generator(bit())
            gen.bit_generator.state = node["state"]
            self.memo[n] = gen
            return gen
        if t in ("list", "deque"):
            out = [] if t == "list" else deque(maxlen=node["maxlen"])
            self.memo[n] = out
            out.extend(self.decode(x) for x in node["v"])
            return out
        if t in ("tuple", "set", "frozenset"):
            out = {"tuple": tuple, "set": set, "frozenset": frozenset}[t](
                self.decode(x) for x in node["v"])
            self.memo[n] = out
            return out
        if t in ("dict", "OrderedDict", "Counter"):
            out = {"dict": dict, "OrderedDict": OrderedDict, "Counter": Counter}[t]()
            self.memo[n] = out
            for k, x in zip(node["k"], node["v"]):
                out[self.decode(k)] = self.decode(x)
            return out
        if t == "obj":
            cls = _aerotrack_class(node["m"], node["c"])
            out = cls.__new__(cls)
            self.memo[n] = out
            for k, x in node["d"].items():
                object.__setattr__(out, k, self.decode(x))  # frozen dataclasses too
            return out
        raise ValueError(f"unknown node type {t!r}")


def _slots(cls: type) -> list[str]:
    """Every slot name of ``cls`` and its bases."""
    out: list[str] = []
    for c in cls.__mro__:
        names = c.__dict__.get("__slots__", ())
        out.extend([names] if isinstance(names, str) else names)
    return [k for k in dict.fromkeys(out) if k not in ("__weakref__", "__dict__")]


def _aerotrack_class(module: str, qualname: str) -> type:
    """A class of the aerotrack package (and only there) by module and qualified name."""
    if module.split(".")[0] != "aerotrack":
        raise ValueError(f"class outside aerotrack: {module}")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    if not isinstance(obj, type):
        raise ValueError(f"{module}.{qualname} is not a class")  # noqa: TRY004  bad file content (UNREADABLE)
    return obj


def save_state(folder: str | Path, frame: int, stages: dict[str, tuple[object, dict]],
               extra: dict | None = None, shared: tuple = (),
               frames: Rereadable | None = None) -> Path:
    """Write the working state of ``stages`` after ``frame`` to ``folder/state.npz``.

    Parameters
    ----------
    folder : path
        The run's ``.partial/``.
    frame : int
        The last frame every stage has taken (1-based); the resumed run continues after it.
    stages : dict of name -> (object, fingerprints)
        Each stage object with :func:`as_built` of it; attributes still as built are left out.
    extra : dict, optional
        Plain JSON values stored beside (the pipeline's own counters).
    shared : tuple
        Objects the caller gave the stages (the map): an attribute that is one of them is not
        saved, the resumed run's constructor gets it again.
    frames : Rereadable, optional
        The frames the stages still hold and what they derive from them: an array equal to one
        of them byte for byte is saved as a reference (frame, kind, CRC-32), and
        :func:`load_state` needs that frame again.

    Raises
    ------
    StateNotSaved
        A stage holds a value of a type this codec does not write (nothing is written then).
    """
    enc = _Encoder(frames)
    tree = {}
    for name, (obj, built) in stages.items():
        attrs = {}
        for k, v in vars(obj).items():
            if (k in built and built[k] == _fingerprint(v)) \
                    or any(v is o for o in shared if o is not None):
                continue
            attrs[k] = enc.encode(v, f"{name}.{k}")
        tree[name] = {"m": type(obj).__module__, "c": type(obj).__qualname__, "d": attrs}
    meta = {"version": _VERSION, "frame": int(frame), "stages": tree, "extra": extra or {},
            "frames": sorted({int(x) for x in _frame_refs(tree)})}
    path = Path(folder) / STATE_FILE
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, __meta__=np.array(json.dumps(meta)), **enc.arrays)
    return path


def _frame_refs(node: Any) -> Iterator[int]:
    """Frame numbers of the frame references in an encoded tree."""
    if isinstance(node, dict):
        if node.get("t") == "frame":
            yield node["f"]
            return
        for v in node.values():
            yield from _frame_refs(v)
    elif isinstance(node, list):
        for v in node:
            yield from _frame_refs(v)


def load_state(folder: str | Path,
               read_frames: Callable[[list[int]], Mapping[int, np.ndarray]] | None = None,
               derive: Mapping[str, Callable[[np.ndarray], np.ndarray]] | None = None,
               ) -> tuple[int, dict[str, tuple[str, dict[str, Any]]], dict] | None:
    """Read ``folder/state.npz``: (frame, {stage: (class name, attributes)}, extra), or None
    when there is none.

    Parameters
    ----------
    read_frames : callable, optional
        Frame numbers -> {frame: image}, the images as the stages were given them (same
        source, same undistortion): called once with the frames the state refers to.
    derive : mapping, optional
        The :attr:`Rereadable.derive` functions the state was saved with.

    Raises
    ------
    InputError
        The file is there but unreadable (the message names it).
    FramesChanged
        The state refers to frames and ``read_frames`` is missing, or gives other pixels than
        were saved (checked by CRC-32): exact resume is then impossible.
    """
    path = Path(folder) / STATE_FILE
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # closed if damaged
            meta = json.loads(str(z["__meta__"][()]))
            if meta.get("version") not in (1, _VERSION):
                return None
            arrays = {k: z[k] for k in z.files if k != "__meta__"}
    except UNREADABLE as exc:
        raise _unreadable(path, exc) from None
    wanted = [int(f) for f in meta.get("frames", [])]
    if wanted and read_frames is None:
        raise FramesChanged(f"the state refers to frames {wanted[0]}-{wanted[-1]} and no "
                            "input was given to re-read them")
    images = read_frames(wanted) if wanted else {}
    try:
        dec = _Decoder(arrays, images, derive)
        stages = {name: (f"{s['m']}.{s['c']}", {k: dec.decode(x) for k, x in s["d"].items()})
                  for name, s in meta["stages"].items()}
    except FramesChanged:
        raise
    except (*UNREADABLE, ImportError) as exc:
        raise _unreadable(path, exc) from None
    return int(meta["frame"]), stages, meta.get("extra", {})


def saved_frame(folder: str | Path) -> tuple[int, dict] | None:
    """(frame, extra) of ``folder/state.npz`` without decoding the stages (None when there is
    no readable state): whether the state is stale, and what to construct before loading it."""
    path = Path(folder) / STATE_FILE
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # closed if damaged
            meta = json.loads(str(z["__meta__"][()]))
    except UNREADABLE as exc:
        if path.is_file():
            raise _unreadable(path, exc) from None
        return None
    if meta.get("version") not in (1, _VERSION):
        return None
    return int(meta["frame"]), meta.get("extra", {})


def apply_state(obj: object, attrs: dict[str, Any]) -> None:
    """Put saved attributes back on a freshly constructed stage object."""
    for k, v in attrs.items():
        setattr(obj, k, v)


def drop_state(folder: str | Path) -> None:
    """Remove ``folder/state.npz`` (stale once later checkpoints exist)."""
    (Path(folder) / STATE_FILE).unlink(missing_ok=True)
    shutil.rmtree(Path(folder) / STATE_TRACKLETS, ignore_errors=True)


def input_fingerprints(paths) -> dict[str, list[int]]:
    """Resolved path -> (bytes, latest modification time in ns) of each input file given; a
    folder counts the image files a run reads from it and sums their sizes (``[files, bytes,
    latest time]``: hidden files and others left out, so that a file browser's ``.DS_Store`` or
    a README does not make it another input; a MOTChallenge sequence's images in its ``imDir``).
    Streams and missing paths are left out."""
    import os

    from .frames import IMAGE_SUFFIXES, mot_sequence

    out = {}
    for p in paths:
        if p is None or "://" in str(p):
            continue
        path = Path(p)
        try:
            if path.is_dir():
                try:
                    seq = mot_sequence(path)
                except InputError:
                    seq = None
                images = seq[0] if seq is not None else path
                files = [e.stat() for e in os.scandir(images) if e.is_file()
                         and not e.name.startswith(".")
                         and os.path.splitext(e.name)[1].lower() in IMAGE_SUFFIXES]
                out[str(path.resolve())] = [len(files), sum(f.st_size for f in files),
                                            max((f.st_mtime_ns for f in files), default=0)]
            elif path.is_file():
                st = path.stat()
                out[str(path.resolve())] = [st.st_size, st.st_mtime_ns]
        except OSError:
            continue
    return out
