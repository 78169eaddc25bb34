"""``aerotrack``: the command group, logging set-up and the one-line error contract.

Every deliberate error (:class:`~aerotrack.errors.AerotrackError`) becomes one line on stderr and
exit code 2; click's own usage errors (a mistyped option value, a missing option) become one line
with exit code 2 too. Ctrl-C or SIGTERM exits with 128 + the signal number. Commands live one per
module in this package and are registered in ``COMMANDS``.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys

import click

from .. import __version__
from ..errors import AerotrackError

# (module in aerotrack.cli, attribute): one entry per subcommand.
COMMANDS = [
    ("eval_cmd", "eval_command"),
    ("synth_cmd", "synth_command"),
    ("track_cmd", "track_command"),
    ("detect_cmd", "detect_command"),
    ("predict_cmd", "predict_command"),
    ("mosaic_cmd", "mosaic_command"),
    ("demo_cmd", "demo_command"),
    ("render_cmd", "render_command"),
    ("report_cmd", "report_command"),
    ("batch_cmd", "batch_command"),
    ("count_cmd", "count_command"),
    ("config_cmd", "config_command"),
]

log = logging.getLogger("aerotrack")


#: Environment that silences FFmpeg's and OpenCV's own messages unless -vv.
_QUIET_LIBS = {"OPENCV_FFMPEG_LOGLEVEL": "-8", "OPENCV_LOG_LEVEL": "ERROR"}  # -8: AV_LOG_QUIET
_set_by_us: set[str] = set()


def configure_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    for name, value in _QUIET_LIBS.items():
        # FFmpeg and OpenCV print to stderr themselves; our own message says it once
        if verbose < 2 and name not in os.environ:
            os.environ[name] = value
            _set_by_us.add(name)
        elif verbose >= 2 and name in _set_by_us:  # -vv after the subcommand: undo our own
            os.environ.pop(name, None)
            _set_by_us.discard(name)
    cv2 = sys.modules.get("cv2")  # already imported: OPENCV_LOG_LEVEL is read at import only
    utils = getattr(getattr(cv2, "utils", None), "logging", None)
    if utils is not None and "OPENCV_LOG_LEVEL" not in os.environ.keys() - _set_by_us:
        utils.setLogLevel(utils.LOG_LEVEL_INFO if verbose >= 2 else utils.LOG_LEVEL_ERROR)
    # Dask's client, closed under a pending gather by Ctrl-C, leaves a task whose AllExit asyncio
    # reports as "Task exception was never retrieved" with a traceback: not ours to show
    logging.getLogger("asyncio").setLevel(logging.CRITICAL if verbose < 2 else logging.NOTSET)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("aerotrack: %(levelname)s: %(message)s"))
    root = logging.getLogger("aerotrack")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


@click.group(
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)
@click.version_option(__version__, "--version", prog_name="aerotrack")
@click.option("-v", "--verbose", count=True,
              help="More messages: progress lines also when stderr is not a terminal; -vv for "
                   "debug messages, FFmpeg's and OpenCV's included.")
@click.option("-q", "--quiet", is_flag=True, help="Only warnings and errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Persistent multi-target tracking in aerial video from a moving platform.

    Finds every moving vehicle without a trained detector, keeps one ID per object through
    occlusions and exits from the view, and reports positions in map and lon/lat coordinates.

    \b
    Quick start:
      aerotrack demo                       # render a scene, track it, write a report
      aerotrack track video.mp4 --out run/ --map map.tif --map-init h.txt
      aerotrack eval --gt gt.txt --pred run/tracks.csv

    \b
    Exit codes: 0 done; 2 bad input or options, or results that cannot be written (a full
    disk, no permission): one line on stderr says which; 130 / 143 stopped by Ctrl-C / SIGTERM
    (what was finished is kept, --resume continues a track run); 1 an unexpected error (a bug:
    the traceback is shown). Results go to files; stdout carries only what a command prints
    (eval's table or --json, count's totals), and with -vv OpenCV's own log lines.
    """
    configure_logging(verbose, quiet)
    ctx.obj = {"verbose": verbose, "quiet": quiet}


def _also_here(ctx: click.Context, param: click.Parameter, value) -> None:
    """``-v`` / ``-q`` given after the subcommand (``aerotrack track ... -v``) add to the ones
    given before it: the group's flags are updated and logging set up again."""
    if not value:
        return
    root = ctx.find_root()
    obj = root.obj if isinstance(root.obj, dict) else {"verbose": 0, "quiet": False}
    if param.name == "verbose_here":
        obj["verbose"] = int(obj.get("verbose", 0)) + int(value)
    else:
        obj["quiet"] = True
    root.obj = obj
    configure_logging(obj["verbose"], obj["quiet"])


def verbosity_options() -> list[click.Option]:
    """The group's ``-v`` and ``-q``, accepted by every subcommand too."""
    return [
        click.Option(["-v", "--verbose", "verbose_here"], count=True, expose_value=False,
                     callback=_also_here,
                     help="More messages (as `aerotrack -v`)."),
        click.Option(["-q", "--quiet", "quiet_here"], is_flag=True, expose_value=False,
                     callback=_also_here,
                     help="Only warnings and errors (as `aerotrack -q`)."),
    ]


def _register() -> None:
    for module, attr in COMMANDS:
        try:
            mod = importlib.import_module(f".{module}", __package__)
        except ModuleNotFoundError as exc:
            if exc.name == f"{__package__}.{module}":
                continue  # command not built yet
            raise
        command = getattr(mod, attr)
        taken = {o for p in command.params for o in getattr(p, "opts", ())}
        command.params.extend(o for o in verbosity_options() if not taken & set(o.opts))
        cli.add_command(command)


_register()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the CLI, mapping aerotrack errors to exit code 2."""
    import signal
    import threading

    from .common import Interrupted

    def terminate(signum, frame):  # SIGTERM unwinds like Ctrl-C: commands clean up after them
        raise Interrupted(signum)

    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, terminate)
    try:
        cli.main(args=argv, prog_name="aerotrack", standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt) as exc:
        # click turns KeyboardInterrupt into Abort; the cause says which signal and what was kept.
        # The run is over: a further Ctrl-C while the process shuts down (a local Dask cluster
        # closing) killed it by SIGINT with a KeyboardInterrupt traceback instead of exit 130
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        cause = exc.__cause__ if isinstance(exc, click.exceptions.Abort) else exc
        click.echo(f"aerotrack: interrupted{getattr(cause, 'note', '')}", err=True)
        sys.exit(128 + int(getattr(cause, "signum", 2)))
    except getattr(click.exceptions, "NoArgsIsHelpError", ()) as exc:  # bare `aerotrack`: the help
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.UsageError as exc:
        # a bad option or argument: one line naming it, like every other bad input
        where = exc.ctx.command_path if exc.ctx is not None else "aerotrack"
        message = " ".join(exc.format_message().split())
        click.echo(f"aerotrack: error: {message} (see '{where} --help')", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except AerotrackError as exc:
        click.echo(f"aerotrack: error: {exc}", err=True)
        sys.exit(2)
    except MemoryError:
        click.echo("aerotrack: error: out of memory (a --map raster is read whole: crop a "
                   "large one to the flight's area, e.g. gdal_translate -projwin)", err=True)
        sys.exit(2)
    except OSError as exc:
        import errno

        # a full disk, a quota, a read-only or forbidden place met mid-run (synth's frames, a
        # picture): the system's words and the file, not a traceback
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM):
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"aerotrack: error: {where}{exc.strerror or exc}", err=True)
        sys.exit(2)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    main()
