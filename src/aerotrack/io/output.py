"""Atomic outputs and the output-folder protocol of the CLI contract.

Final files appear atomically: each is written beside its destination under a temporary name and
renamed into place (``os.replace``), so a killed run never leaves a file that looks complete. Work in
progress lives in ``DIR/.partial/``. Where an :class:`OutputDir` replaces results already there
(``--overwrite``, ``--resume``), its results are written into ``DIR/.partial/out/`` and moved
into ``DIR`` together once all are written (:meth:`OutputDir.finish`): the earlier run's results
stay until then (a run that failed or was stopped left an empty folder), and a run that fails
while writing (a full disk) leaves them as they were.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from ..errors import OutputError

PARTIAL = ".partial"
#: Inside ``.partial/``: a run's finished results, until :meth:`OutputDir.finish` moves them in.
STAGED = "out"
#: Inside ``.partial/``: the earlier run's entries an ``--overwrite`` run replaces when it ends.
REPLACED = "replaced.txt"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _umask()


def _why_not(path: Path, exc: OSError) -> str:
    """Why ``path`` cannot be written, in words: a file standing where a folder must be is named
    (the system only says 'File exists' or 'Not a directory')."""
    for anc in Path(path).parents:
        if anc.exists():
            if not anc.is_dir():
                return f"{anc} is a file, not a folder"
            break
    return exc.strerror or str(exc)


def check_writable(path: str | Path, option: str, *, folder: bool = False) -> None:
    """Refuse, before any work, an output ``path`` that cannot be written: a folder where a file
    is wanted (or the reverse), a file where a parent folder must be, no permission, a read-only
    place. Nothing is left behind (the probe file is removed, no folder is made).

    Raises
    ------
    OutputError
        One line naming ``option`` and ``path``.
    """
    p = Path(path)
    if p.exists() and folder != p.is_dir():
        what = "is a folder; give a file name" if not folder else "exists and is not a folder"
        raise OutputError(f"{option} {p}: {what}")
    anc = p if folder and p.is_dir() else next(a for a in p.parents if a.exists())
    if not anc.is_dir():
        raise OutputError(f"{option} {p}: cannot write there ({anc} is a file, not a folder)")
    try:
        fd, probe = tempfile.mkstemp(prefix=".aerotrack-probe-", suffix=".tmp", dir=anc)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{option} {p}: cannot write there ({exc.strerror or exc})") from None


def check_apart(out: str | Path, option: str, inputs, *, run_dir: str | Path | None = None,
                own: tuple[str, ...] = ()) -> None:
    """Refuse an output that would replace or write into an input: ``out`` is one of ``inputs``
    (``(label, path)`` pairs, paths may be None) or inside an input folder; or, with
    ``run_dir`` (a run folder the command reads), one of that run's results other than the
    command's ``own`` files (``report --out run/tracks.csv`` replaced the tracks by HTML).

    Raises
    ------
    OutputError
        One line naming ``option``, ``out`` and the input.
    """
    o = Path(out).resolve()
    for label, path in inputs:
        if path is None:
            continue
        q = Path(path).resolve()
        if o == q:
            raise OutputError(f"{option} {out}: is the {label} ({path}): it would be replaced; "
                              "write elsewhere")
        if q.is_dir() and q in o.parents:
            raise OutputError(f"{option} {out}: is inside the {label} folder ({path}); write "
                              "elsewhere")
    if run_dir is not None and o.parent == Path(run_dir).resolve() and o.name not in own \
            and (o.name in OUTPUT_NAMES or o.suffix.lower() in (".csv", ".json", ".toml",
                                                                  ".geojson")) and o.exists():
        raise OutputError(f"{option} {out}: is one of the run's own results (it would be "
                          "replaced); write elsewhere")


def check_outside(out_dir: str | Path, option: str, inputs) -> None:
    """Refuse an output folder that holds one of the ``inputs`` (``(label, path)`` pairs, None
    skipped): its results replace the folder's content (``track --out q --overwrite`` of
    ``q/overlay.webm`` deleted the video it was reading)."""
    o = Path(out_dir).resolve()
    for label, path in inputs:
        if path is None or "://" in str(path):
            continue
        q = Path(path).resolve()
        if q == o or o in q.parents:
            raise OutputError(f"{option} {out_dir}: holds the {label} ({path}), which its "
                              "results would replace; give an output folder apart from the "
                              "inputs")


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success rename it to ``path``, on error delete it.

    Raises
    ------
    OutputError
        The file cannot be written there (no such folder and none can be made, no permission,
        a folder in the way, disk full): one line naming ``path``.
    """
    path = Path(path)
    if path.is_symlink():  # the link's target is written (renaming over the link replaced it)
        path = Path(os.path.realpath(path))
    if path.exists() and not path.is_file():
        import stat

        if not path.is_dir() and not stat.S_ISREG(path.stat().st_mode):
            raise OutputError(f"{path}: not a regular file (a device, a pipe): aerotrack writes "
                              "its results to files")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; results are as readable as any new file
    except OSError as exc:
        raise OutputError(f"{path}: cannot write there ({_why_not(path, exc)})") from None
    if "b" not in mode:
        # a file name that is not valid UTF-8 (held with surrogate escapes) in a report or a
        # table stopped the write with a traceback: it is written escaped (``\udced``)
        kwargs.setdefault("errors", "backslashreplace")
    try:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_write(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_write(path, "wb") as fh:
        fh.write(data)


#: In ``.partial/``: the host and process writing the folder (:func:`_running_owner`).
OWNER = "owner"


def _start_time(pid: int) -> str:
    """The process's start time in clock ticks since boot (Linux ``/proc``), or "" elsewhere: with
    the pid it tells a process from a later one given the same number."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            return fh.read().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return ""


def _owner_record(pid: int) -> str:
    import socket

    return f"{socket.gethostname()} {pid} {_start_time(pid)}\n"


def _running_owner(partial: Path) -> int | None:
    """The pid of the process on this host still writing into the folder of ``partial``, or
    None (no record, another host's, or a process that has ended: an interrupted run)."""
    import socket

    try:
        parts = (partial / OWNER).read_text(encoding="utf-8").split()
        host, pid = parts[0], int(parts[1])
        started = parts[2] if len(parts) > 2 else ""
    except (OSError, ValueError, IndexError):
        return None
    if host != socket.gethostname() or pid == os.getpid():
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # another user's process: alive
        pass
    if started and _start_time(pid) not in ("", started):
        return None  # its number was given to a later process
    return pid


class OutputDir:
    """An output folder under the contract's rules.

    ``--out`` may be missing or an existing empty folder. A folder that already holds results is
    refused unless ``overwrite`` (results are replaced) or ``resume`` (``.partial/`` is kept and
    continued from) is set.

    Parameters
    ----------
    path : path
        The folder.
    overwrite, resume : bool
        What to do with a folder that already holds results (mutually exclusive).
    option : str
        Option name used in messages (``--out``).
    resumable : bool
        Whether the command has ``--resume`` (``track``, ``batch``), for the message that refuses
        a folder holding results.
    stage : bool
        Write results into :attr:`staged` for :meth:`finish` to move in even into a new folder
        (the command line: a run that fails while writing them leaves none). Without it a new
        folder's results are written in place.
    """

    def __init__(self, path: str | Path, *, overwrite: bool = False, resume: bool = False,
                 option: str = "--out", resumable: bool = False, stage: bool = False) -> None:
        if overwrite and resume:
            raise OutputError("--overwrite and --resume cannot be used together")
        self.path = Path(path)
        self.resume = resume
        p = self.path
        if p.exists() and not p.is_dir():
            raise OutputError(f"{option} {p}: exists and is not a folder")
        if p.is_dir():
            entries = [e for e in p.iterdir()]
            busy = _running_owner(p / PARTIAL)
            if busy is not None:
                # (a run still going was called "an interrupted run", and the advice to
                # --resume or --overwrite it ran two at once into one folder: an ops probe)
                raise OutputError(f"{option} {p}: another aerotrack (process {busy}) is writing "
                                  "into it; wait for it to end, or give another folder")
            if entries and not (overwrite or resume):
                foreign = sorted(e.name for e in entries if not is_aerotrack_output(e.name))
                if foreign:
                    raise OutputError(f"{option} {p}: folder holds files aerotrack did not write "
                                      f"(e.g. {foreign[0]!r}); give a new or empty folder")
                if resumable and (p / PARTIAL).is_dir():
                    raise OutputError(f"{option} {p}: holds an interrupted run ({PARTIAL}/): "
                                      "--resume continues it, --overwrite starts again")
                if resumable and not (p / "summary.json").exists():
                    raise OutputError(f"{option} {p}: holds an unfinished run (its results are "
                                      "not all written: no summary.json): --resume finishes it, "
                                      "--overwrite starts again")
                raise OutputError(f"{option} {p}: folder already holds results; use --overwrite"
                                  + (" or --resume" if resumable else ""))
        #: the earlier run's entries, replaced by :meth:`finish` (``overwrite``); until then they
        #: stay, so a run that fails or is stopped leaves them as they were
        self._replaced: list[str] = []
        self._staging = False
        try:
            if p.is_dir() and overwrite:
                self._replaced = [e.name for e in entries if e.name != PARTIAL]
                if (p / PARTIAL).exists():  # an interrupted run's work: started again
                    _remove(p / PARTIAL)
            p.mkdir(parents=True, exist_ok=True)
            self.partial.mkdir(exist_ok=True)
            if self.staged.exists():  # results of a resumed run that failed while writing them
                _remove(self.staged)
            record = self.partial / REPLACED
            if self._replaced:  # (a resumed --overwrite run still replaces them all)
                record.write_text("\n".join(self._replaced) + "\n", encoding="utf-8")
            elif resume and record.is_file():
                self._replaced = [n for n in record.read_text(encoding="utf-8").splitlines()
                                  if n and (p / n).exists()]
            # results already there are replaced together at the end; a new folder's are written
            # in place (the Python API reads them from ``path`` without calling ``finish``)
            self._staging = stage or bool(self._replaced) or resume
            probe = self.partial / ".write-test"
            probe.write_text("")
            probe.unlink()
            (self.partial / OWNER).write_text(_owner_record(os.getpid()), encoding="utf-8")
        except OSError as exc:
            raise OutputError(f"{option} {p}: cannot write there ({_why_not(p, exc)})") from None

    @property
    def partial(self) -> Path:
        """Folder for work in progress (kept on interruption, used by ``--resume``)."""
        return self.path / PARTIAL

    @property
    def staged(self) -> Path:
        """Where results are written until :meth:`finish` moves them into the folder."""
        return self.partial / STAGED

    def file(self, name: str) -> Path:
        """The path to write result ``name`` to: in :attr:`staged` until :meth:`finish` where
        they replace results already there (``overwrite``, ``resume``), else in the folder."""
        if not self._staging:
            return self.path / name
        self.staged.mkdir(parents=True, exist_ok=True)
        return self.staged / name

    def write_text(self, name: str, text: str) -> Path:
        dest = self.file(name)
        atomic_write_text(dest, text)
        return dest

    def finish(self, keep_as: str | None = None) -> None:
        """Once every result is written: the earlier run's entries (``overwrite``) go, the results
        move into the folder, and ``.partial/`` is removed, or kept under the name ``keep_as``
        (``stages/``: cached registrations and detections for ``track --from``)."""
        try:
            for name in self._replaced:
                _remove(self.path / name)
            (self.partial / REPLACED).unlink(missing_ok=True)
            (self.partial / OWNER).unlink(missing_ok=True)  # (not kept in stages/)
            if self.staged.is_dir():
                for e in sorted(self.staged.iterdir()):
                    dest = self.path / e.name
                    if dest.is_dir() and not dest.is_symlink():
                        shutil.rmtree(dest)  # (os.replace moves a folder onto an empty one only)
                    os.replace(e, dest)
                self.staged.rmdir()
            if keep_as is None:
                shutil.rmtree(self.partial, ignore_errors=True)
                return
            dest = self.path / keep_as
            shutil.rmtree(dest, ignore_errors=True)
            os.replace(self.partial, dest)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot move the results into place "
                              f"({exc.strerror or exc})") from None
        finally:
            self._replaced = []


def _remove(path: Path) -> None:
    """Remove a file, a link or a folder tree."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


#: Top-level names any aerotrack command writes into an output folder.
OUTPUT_NAMES = {
    "tracks.csv", "predicted.csv", "links.csv", "detections.csv", "registration.csv",
    "tracks.geojson",
    "config.toml", "summary.json", "observations.csv", "observations.gpkg",
    "observations.parquet", "track_segments.gpkg", "stages", ".partial", "overlay.webm", "overlay.mp4", "map.png",
    "spacetime.png", "registration.png", "report.html", "debug.mp4",
    # synth
    "frames", "gt.txt", "states.csv", "homographies.csv", "map.tif", "map_init.txt",
    "map_init_gcps.csv", "map_init_lonlat.csv", "occluders.csv", "occluders.geojson",
    "roads.geojson", "scenario.json",
    # demo
    "scene", "run",
    # count
    "crossings.csv", "counts.csv", "movements.csv", "count_lines.png",
    # batch (its lock, in --out)
    ".batch.lock",
}


#: Files a desktop's file browser drops into any folder it shows (macOS Finder, Windows
#: Explorer): no user data, so they neither make an output folder foreign nor survive --overwrite.
BROWSER_FILES = {".DS_Store", "Thumbs.db", "desktop.ini", ".directory"}


def is_aerotrack_output(name: str) -> bool:
    """Whether an entry named ``name`` at the top of a folder is one aerotrack writes (or a file
    browser's clutter, :data:`BROWSER_FILES` and macOS's ``._*`` companions)."""
    return (name in OUTPUT_NAMES or name in BROWSER_FILES or name.startswith("._")
            or (name.startswith(".") and name.endswith(".tmp")))
