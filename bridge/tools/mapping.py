"""The replay mapping file: which recorded stream carries what, and how interactions are segmented.

A TOML file (read with the standard library's ``tomllib``), shared by ROS bags
(:mod:`bridge.tools.bags`, streams are topics) and yarpdatadumper logs
(:mod:`bridge.tools.yarp`, streams are dump folders). docs/bridge.md has the full
format and an example; every problem is an :class:`InvalidRecordingError` whose
field is the mapping key (``mapping.haptics.reduce``).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.errors import InvalidRecordingError

REDUCTIONS = ("mean", "sum", "max")
#: ``haptics.component`` of a geometry_msgs/msg/WrenchStamped: one axis, or the force's magnitude.
WRENCH_COMPONENTS = ("force.x", "force.y", "force.z", "force.norm", "torque.x", "torque.y", "torque.z", "torque.norm")
SAMPLE_FORMATS = ("S16LE", "S32LE", "F32LE")
ANGLE_UNITS = ("rad", "deg")


@dataclass(frozen=True)
class Clouds:
    """The streams of the look, before and after snapshots (may all be one camera stream)."""

    look: str
    before: str
    after: str
    scale: float = 1.0


@dataclass(frozen=True)
class AudioStream:
    """Audio: raw PCM bytes (``sample_format``) or float arrays, interleaved over ``channels``."""

    source: str
    sample_rate: int
    channels: int = 1
    sample_format: str = "S16LE"
    behaviours: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Proprioception:
    """The finger joint: a JointState ``joint`` name (bags) or a column index (yarp)."""

    source: str
    joint: str | int
    unit: str = "rad"
    behaviours: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Haptics:
    """Tactile or force readings, reduced to one value per message."""

    source: str
    indices: tuple[int, ...] | None = None
    reduce: str = "mean"
    component: str = "force.norm"
    behaviours: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Windows:
    """A fixed schedule: each object is a look of ``look`` s then one ``interaction`` s window per behaviour."""

    behaviours: tuple[str, ...]
    look: float
    interaction: float
    objects_per_scene: int = 1
    start: float = 0.0


@dataclass(frozen=True)
class Mapping:
    """One mapping file read and checked."""

    clouds: Clouds
    markers: str | None = None
    windows: Windows | None = None
    audio: AudioStream | None = None
    proprioception: Proprioception | None = None
    haptics: Haptics | None = None
    yarp_timestamps: int = 1

    @property
    def streams(self) -> dict[str, str]:
        """Role -> stream name, for every stream the mapping reads (markers included)."""
        roles = {
            "clouds.look": self.clouds.look,
            "clouds.before": self.clouds.before,
            "clouds.after": self.clouds.after,
        }
        for role, stream in (("audio", self.audio), ("proprioception", self.proprioception), ("haptics", self.haptics)):
            if stream is not None:
                roles[role] = stream.source
        if self.markers is not None:
            roles["segmentation.markers"] = self.markers
        return roles


def read_mapping(path: Path) -> Mapping:
    """Read and check a mapping file."""
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as error:
        raise InvalidRecordingError(str(path), f"cannot be read as a TOML mapping: {error}") from None
    return parse_mapping(table)


def parse_mapping(table: dict[str, Any]) -> Mapping:
    """A mapping from its TOML table (see the module docstring)."""
    _only(table, "mapping", {"clouds", "audio", "proprioception", "haptics", "segmentation", "yarp"})
    mapping = Mapping(
        clouds=_clouds(_required_section(table, "clouds")),
        audio=_audio(_section(table, "audio")),
        proprioception=_proprioception(_section(table, "proprioception")),
        haptics=_haptics(_section(table, "haptics")),
        **_segmentation(_required_section(table, "segmentation")),
        **_yarp(_section(table, "yarp")),
    )
    if (mapping.proprioception is None) != (mapping.haptics is None):
        raise InvalidRecordingError(
            "mapping.haptics", "and mapping.proprioception go together: a finger series needs both"
        )
    return mapping


def _required_section(table: dict[str, Any], name: str) -> dict[str, Any]:
    section = _section(table, name)
    if section is None:
        raise InvalidRecordingError(f"mapping.{name}", "is missing")
    return section


def _section(table: dict[str, Any], name: str) -> dict[str, Any] | None:
    section = table.get(name)
    if section is not None and not isinstance(section, dict):
        raise InvalidRecordingError(f"mapping.{name}", "must be a table")
    return section


def _only(table: dict[str, Any], field: str, allowed: set[str]) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InvalidRecordingError(field, f"has unknown keys {unknown} (allowed: {sorted(allowed)})")


def _get(section: dict[str, Any], field: str, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
    if key not in section:
        if default is ...:
            raise InvalidRecordingError(f"{field}.{key}", "is missing")
        return default
    value = section[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise InvalidRecordingError(f"{field}.{key}", f"has the wrong type ({type(value).__name__})")
    return value


def _choice(section: dict[str, Any], field: str, key: str, choices: tuple[str, ...], default: str) -> str:
    value = _get(section, field, key, str, default)
    if value not in choices:
        raise InvalidRecordingError(f"{field}.{key}", f"is {value!r}, expected one of {list(choices)}")
    return value


def _source(section: dict[str, Any], field: str) -> str:
    """``topic`` (bags) or ``folder`` (yarp dump folders): exactly one."""
    given = [key for key in ("topic", "folder") if key in section]
    if len(given) != 1:
        raise InvalidRecordingError(field, "needs exactly one of topic (bags) or folder (yarp logs)")
    return _get(section, field, given[0], str)


def _behaviours(section: dict[str, Any], field: str) -> tuple[str, ...] | None:
    behaviours = _get(section, field, "behaviours", list, None)
    return None if behaviours is None else tuple(str(name) for name in behaviours)


def _clouds(section: dict[str, Any]) -> Clouds:
    field = "mapping.clouds"
    _only(section, field, {"topic", "folder", "look", "before", "after", "scale"})
    default = section.get("topic", section.get("folder"))
    roles = {role: _get(section, field, role, str, default) for role in ("look", "before", "after")}
    missing = [role for role, stream in roles.items() if stream is None]
    if missing:
        raise InvalidRecordingError(field, f"names no stream for {missing}: give topic, or look, before and after")
    scale = float(_get(section, field, "scale", (int, float), 1.0))
    if scale <= 0:
        raise InvalidRecordingError(f"{field}.scale", "must be positive")
    return Clouds(**roles, scale=scale)


def _audio(section: dict[str, Any] | None) -> AudioStream | None:
    if section is None:
        return None
    field = "mapping.audio"
    _only(section, field, {"topic", "folder", "sample_rate", "channels", "sample_format", "behaviours"})
    channels = _get(section, field, "channels", int, 1)
    if channels < 1:
        raise InvalidRecordingError(f"{field}.channels", "must be at least 1")
    return AudioStream(
        source=_source(section, field),
        sample_rate=_get(section, field, "sample_rate", int),
        channels=channels,
        sample_format=_choice(section, field, "sample_format", SAMPLE_FORMATS, "S16LE"),
        behaviours=_behaviours(section, field),
    )


def _proprioception(section: dict[str, Any] | None) -> Proprioception | None:
    if section is None:
        return None
    field = "mapping.proprioception"
    _only(section, field, {"topic", "folder", "joint", "column", "unit", "behaviours"})
    if ("joint" in section) == ("column" in section):
        raise InvalidRecordingError(field, "needs exactly one of joint (a JointState name) or column (a yarp column)")
    joint = _get(section, field, "joint", str) if "joint" in section else _get(section, field, "column", int)
    return Proprioception(
        source=_source(section, field),
        joint=joint,
        unit=_choice(section, field, "unit", ANGLE_UNITS, "rad" if "joint" in section else "deg"),
        behaviours=_behaviours(section, field),
    )


def _haptics(section: dict[str, Any] | None) -> Haptics | None:
    if section is None:
        return None
    field = "mapping.haptics"
    _only(section, field, {"topic", "folder", "indices", "columns", "reduce", "component", "behaviours"})
    indices = section.get("indices", section.get("columns"))
    if indices is not None and not (
        isinstance(indices, list) and indices and all(isinstance(i, int) and i >= 0 for i in indices)
    ):
        raise InvalidRecordingError(f"{field}.indices", "must be a non-empty list of element (or column) indices")
    return Haptics(
        source=_source(section, field),
        indices=None if indices is None else tuple(indices),
        reduce=_choice(section, field, "reduce", REDUCTIONS, "mean"),
        component=_choice(section, field, "component", WRENCH_COMPONENTS, "force.norm"),
        behaviours=_behaviours(section, field),
    )


def _segmentation(section: dict[str, Any]) -> dict[str, Any]:
    field = "mapping.segmentation"
    _only(section, field, {"markers", "windows"})
    if ("markers" in section) == ("windows" in section):
        raise InvalidRecordingError(field, "needs exactly one of markers (a stream) or windows (a fixed schedule)")
    if "markers" in section:
        return {"markers": _get(section, field, "markers", str)}
    windows = _get(section, field, "windows", dict)
    field = f"{field}.windows"
    _only(windows, field, {"behaviours", "look", "interaction", "objects_per_scene", "start"})
    schedule = Windows(
        behaviours=tuple(str(name) for name in _get(windows, field, "behaviours", list)),
        look=float(_get(windows, field, "look", (int, float))),
        interaction=float(_get(windows, field, "interaction", (int, float))),
        objects_per_scene=_get(windows, field, "objects_per_scene", int, 1),
        start=float(_get(windows, field, "start", (int, float), 0.0)),
    )
    if not schedule.behaviours or schedule.look <= 0 or schedule.interaction <= 0 or schedule.objects_per_scene < 1:
        raise InvalidRecordingError(field, "needs behaviours, and positive look, interaction and objects_per_scene")
    return {"windows": schedule}


def _yarp(section: dict[str, Any] | None) -> dict[str, Any]:
    if section is None:
        return {}
    field = "mapping.yarp"
    _only(section, field, {"timestamps"})
    timestamps = _get(section, field, "timestamps", int, 1)
    if timestamps not in (1, 2):
        raise InvalidRecordingError(f"{field}.timestamps", "is 1 (one stamp per line) or 2 (--txTime with --rxTime)")
    return {"yarp_timestamps": timestamps}
