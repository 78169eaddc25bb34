"""``python -m aerotrack`` runs the CLI."""

import sys


def run() -> None:
    """Console entry point: the CLI; a Ctrl-C while it is still loading ends quietly (exit 130)
    instead of with a traceback of whichever import it landed in."""
    try:
        from .cli.main import main
    except KeyboardInterrupt:
        sys.stderr.write("aerotrack: interrupted\n")
        sys.exit(130)
    main()


if __name__ == "__main__":
    run()
