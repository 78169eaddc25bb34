"""Configuration: one frozen, documented dataclass per stage, loaded from TOML.

Every parameter can be set in a TOML file (``--config FILE``), one table per stage::

    [detection]
    window_s = 3.0

and overridden on the command line (``--set detection.window_s=2``). The resolved configuration is
written as ``config.toml`` beside every output so a run can be repeated exactly.

Time-based settings are in seconds and distances in metres (or world units where no scale is known),
never in frames: a config means the same thing at 10 and at 60 frames/s.

Each stage owns its section; add a parameter by adding a documented field to that section.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .errors import ConfigError


@dataclass(frozen=True)
class RegistrationConfig:
    """Frame-to-frame and frame-to-map registration (Yu & Medioni section 2).

    Attributes
    ----------
    method : str
        Feature tracker for frame-to-frame motion: ``lk`` (sparse optical flow) or ``orb``.
    max_features : int
        Features tracked per frame. Raising it steadies the estimate on low texture but costs time.
    scale : float
        Frames are downscaled by this factor for feature tracking (1 = full resolution).
    ransac_threshold_px : float
        RANSAC inlier threshold, in full-resolution frame pixels.
    min_inliers : int
        Fewer inliers than this is a registration failure.
    refine_every_s : float
        Seconds between map refinements (0 disables periodic refinement).
    """

    method: str = "lk"
    max_features: int = 800
    scale: float = 0.5
    ransac_threshold_px: float = 2.0
    min_inliers: int = 20
    refine_every_s: float = 1.0


@dataclass(frozen=True)
class DetectionConfig:
    """Moving-object detection on registered frames (Yu & Medioni section 3).

    Attributes
    ----------
    window_s : float
        Length of the sliding background window in seconds (the paper: 91 frames = 3 s at 30 fps).
        Longer absorbs fewer slow vehicles but costs memory and fails more with parallax.
    """

    window_s: float = 3.0


@dataclass(frozen=True)
class AssociationConfig:
    """Local data association by data-driven MCMC (Yu & Medioni section 4).

    Attributes
    ----------
    window_s : float
        Sliding association window in seconds (the paper: 45 frames = 1.5 s at 30 fps).
    max_speed_mps : float
        Maximum target speed, metres per second (world units per second without a scale).
    """

    window_s: float = 1.5
    max_speed_mps: float = 40.0


@dataclass(frozen=True)
class LinkingConfig:
    """Global tracklet association (Yu & Medioni section 5) and re-acquisition.

    Attributes
    ----------
    max_gap_s : float
        Longest gap between two tracklets that may still be linked, seconds.
    """

    max_gap_s: float = 12.0


@dataclass(frozen=True)
class ContextConfig:
    """Motion and appearance contexts (Ali, Reilly & Shah section 4).

    Attributes
    ----------
    history_s : float
        Seconds of a target's last observations matched against other tracks (the paper's F).
    prediction_horizon_s : float
        How long an unobserved target's position is predicted into ``predicted.csv``.
    """

    history_s: float = 1.0
    prediction_horizon_s: float = 10.0


@dataclass(frozen=True)
class Config:
    """The whole pipeline's configuration, one section per stage."""

    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    linking: LinkingConfig = field(default_factory=LinkingConfig)
    context: ContextConfig = field(default_factory=ContextConfig)


def _section_types() -> dict[str, type]:
    hints = typing.get_type_hints(Config)
    return {f.name: hints[f.name] for f in fields(Config)}


def _coerce(section: str, key: str, value: Any, typ: Any) -> Any:
    where = f"{section}.{key}"
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.lower() in ("true", "1", "yes")
        raise ConfigError(f"config {where}: expected true or false, got {value!r}")
    if typ is int:
        if isinstance(value, bool):
            raise ConfigError(f"config {where}: expected an integer, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"config {where}: expected an integer, got {value!r}") from None
        if not f.is_integer():
            raise ConfigError(f"config {where}: expected an integer, got {value!r}")
        return int(f)
    if typ is float:
        if isinstance(value, bool):
            raise ConfigError(f"config {where}: expected a number, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"config {where}: expected a number, got {value!r}") from None
        if not math.isfinite(f):
            raise ConfigError(f"config {where}: expected a finite number, got {value!r}")
        return f
    if typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"config {where}: expected a string, got {value!r}")
        return value
    origin = typing.get_origin(typ)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config {where}: expected a list, got {value!r}")
        (inner, *_) = typing.get_args(typ) or (float,)
        return tuple(_coerce(section, key, v, inner) for v in value)
    return value


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a :class:`Config` from nested tables, rejecting unknown sections and keys."""
    sections = _section_types()
    kwargs = {}
    for name, table in data.items():
        if name not in sections:
            raise ConfigError(
                f"config: unknown section [{name}] (valid: {', '.join(sorted(sections))})"
            )
        if not isinstance(table, dict):
            raise ConfigError(f"config: [{name}] must be a table")
        cls = sections[name]
        hints = typing.get_type_hints(cls)
        valid = {f.name for f in fields(cls)}
        values = {}
        for key, value in table.items():
            if key not in valid:
                raise ConfigError(
                    f"config: unknown parameter {name}.{key} (valid: {', '.join(sorted(valid))})"
                )
            values[key] = _coerce(name, key, value, hints[key])
        kwargs[name] = cls(**values)
    return Config(**kwargs)


def config_to_dict(config: Config) -> dict[str, dict[str, Any]]:
    return {f.name: dataclasses.asdict(getattr(config, f.name)) for f in fields(config)}


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Load a TOML config (or the defaults) and apply ``section.key=value`` overrides.

    Raises
    ------
    ConfigError
        The file is unreadable, not TOML, or names an unknown or mistyped parameter.
    """
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{p}: config file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{p}: cannot read config ({exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    for item in overrides:
        key, sep, raw = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot or not name:
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        data.setdefault(section, {})[name] = value
    return config_from_dict(data)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_config(config: Config) -> str:
    """The configuration as TOML text (``load_config`` of it gives back an equal Config)."""
    lines = ["# aerotrack resolved configuration"]
    for section, table in config_to_dict(config).items():
        lines.append(f"\n[{section}]")
        for key, value in table.items():
            lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"
