"""``python -m aerotrack`` runs the CLI."""

from .cli.main import main

main()
