"""Options and helpers shared by several commands."""

from __future__ import annotations

import click

fps_option = click.option(
    "--fps", type=float, default=None,
    help="Frame rate. Defaults to the video's rate, and to 30 for image folders and detections files.",
)
seed_option = click.option("--seed", type=int, default=0, show_default=True,
                           help="Random seed: the same input, config and seed give the same tracks.")
config_option = click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
                             help="TOML file with per-stage parameters (see config.toml of any run).")
set_option = click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
                          help="Override one config parameter (repeatable).")
