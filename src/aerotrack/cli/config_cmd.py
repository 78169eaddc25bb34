"""``aerotrack config``: every setting, its default and what it does."""

from __future__ import annotations

import textwrap

import click

from .common import PathArg


@click.command("config")
@click.argument("name", required=False)
@click.option("--config", "config_path", type=PathArg(path_type=str), default=None,
              help="Show this TOML file's values (defaults for what it leaves out) instead of the "
                   "defaults; a run's own config.toml shows what that run used.")
def config_command(name, config_path):
    """Settings for --config and --set: their values and what they do.

    \b
    aerotrack config                       # every setting, default and first sentence, as TOML
    aerotrack config detection             # one section
    aerotrack config detection.min_area_m2 # one setting, its whole description
    aerotrack config --config run/config.toml linking

    The output without NAME (or with a section) is a valid config file: edit it and give it to
    `aerotrack track --config FILE`.
    """
    import difflib

    from ..config import config_to_dict, describe_settings, first_sentence, load_config, toml_value
    from ..errors import ConfigError

    values = config_to_dict(load_config(config_path))
    docs = describe_settings()
    if name and "." in name:
        if name not in docs:
            close = difflib.get_close_matches(name, list(docs), n=3)
            raise ConfigError(f"config {name}: no such setting"
                              + (f"; did you mean {' or '.join(close)}?" if close else ""))
        section, key = name.split(".", 1)
        click.echo(f"{name} = {toml_value(values[section][key])}")
        click.echo(textwrap.fill(docs[name], width=96, initial_indent="    ",
                                 subsequent_indent="    "))
        return
    if name and name not in values:
        close = difflib.get_close_matches(name, list(values), n=1)
        raise ConfigError(f"config: no section [{name}]"
                          + (f"; did you mean [{close[0]}]?" if close else "")
                          + f" (sections: {', '.join(values)})")
    what = f"values of {config_path}" if config_path else "defaults"
    lines = [f"# aerotrack settings ({what}); `aerotrack config SECTION.KEY` describes one in full"]
    for section, table in values.items():
        if name and section != name:
            continue
        lines.append(f"\n[{section}]")
        for key, value in table.items():
            lines.append(f"# {first_sentence(docs.get(f'{section}.{key}', ''))}")
            lines.append(f"{key} = {toml_value(value)}")
    click.echo("\n".join(lines))
