"""Cut a recording into scenes, objects and interactions: from marker messages or a fixed schedule.

Times are integer nanoseconds on the recording's own clock (a bag's log time,
a yarp log's stamp). The marker grammar (one marker per message, words split
on whitespace; docs/bridge.md)::

    scene                        a new scene starts (the previous one ends); optional for a one-scene recording
    look <object>                the object's look window, up to the next marker
    begin <object> <behaviour>   an interaction window starts ...
    end [<object> <behaviour>]   ... and ends here (the names, when given, must match)

An object belongs to the scene in which it was looked at; its interactions
follow its look. Every problem names the marker's time.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bridge.errors import InvalidRecordingError
from bridge.models import RawObject
from bridge.tools.mapping import Windows

NANOSECONDS = 1_000_000_000


@dataclass(frozen=True)
class Window:
    """[start, stop] in nanoseconds; both ends included, so a marker's own instant belongs to it."""

    start: int
    stop: int

    def holds(self, time: int) -> bool:
        return self.start <= time <= self.stop


@dataclass(frozen=True)
class InteractionPlan:
    behaviour: str
    window: Window


@dataclass
class ObjectPlan:
    name: str
    look: Window
    interactions: list[InteractionPlan] = field(default_factory=list)


@dataclass
class ScenePlan:
    """One scene to post: its objects, and its window (the start time makes its idempotency key)."""

    index: int
    window: Window
    objects: list[ObjectPlan] = field(default_factory=list)


@dataclass(frozen=True)
class SegmentedScene:
    """One scene cut from a recording, read, checked and encoded: its plan, raw objects and idempotency key."""

    plan: ScenePlan
    recordings: list[RawObject]
    key: str


def applies(behaviours: tuple[str, ...] | None, behaviour: str) -> bool:
    """Whether a stream limited to ``behaviours`` (None: every one) is read during ``behaviour``."""
    return behaviours is None or behaviour in behaviours


def format_time(time: int, origin: int) -> str:
    """A time as a reader wants it in an error: seconds from the recording's start, and the raw stamp."""
    return f"t = {(time - origin) / NANOSECONDS:.3f} s (stamp {time} ns)"


def plan_from_markers(
    markers: Iterable[tuple[int, str]], start: int, stop: int, stream: str, *, cut: bool = False
) -> list[ScenePlan]:
    """Scenes from ``(time, text)`` markers in time order; ``start``/``stop`` bound the recording.

    ``cut``: the recording was cut short at ``stop`` (a truncated bag), so an interaction still open
    there ends with it instead of being an error (its scene is the cut one, which is not posted).
    """
    scenes: list[ScenePlan] = []
    scene: ScenePlan | None = None
    looking: ObjectPlan | None = None
    open_interaction: tuple[int, ObjectPlan, str] | None = None

    def problem(time: int, text: str, what: str) -> InvalidRecordingError:
        return InvalidRecordingError(stream, f"marker {text!r} at {format_time(time, start)}: {what}")

    def close_look(time: int) -> None:
        nonlocal looking
        if looking is not None:
            looking.look = Window(looking.look.start, time)
            looking = None

    for time, text in markers:
        words = text.split()
        verb, names = (words[0].lower(), words[1:]) if words else ("", [])
        close_look(time)
        if open_interaction is not None and verb != "end":
            raise problem(time, text, f"interaction {open_interaction[2]!r} of {open_interaction[1].name!r} not ended")
        if verb == "scene":
            scene = ScenePlan(len(scenes), Window(time, stop))
            scenes.append(scene)
        elif verb == "look" and len(names) == 1:
            if scene is None:
                scene = ScenePlan(len(scenes), Window(start, stop))
                scenes.append(scene)
            if any(obj.name == names[0] for obj in scene.objects):
                raise problem(time, text, f"object {names[0]!r} was already looked at in this scene")
            looking = ObjectPlan(names[0], Window(time, stop))
            scene.objects.append(looking)
        elif verb == "begin" and len(names) == 2:
            obj = next((o for o in scene.objects if o.name == names[0]), None) if scene else None
            if obj is None:
                raise problem(time, text, f"object {names[0]!r} has no look marker before it in this scene")
            open_interaction = (time, obj, names[1])
        elif verb == "end" and len(names) in (0, 2):
            if open_interaction is None:
                raise problem(time, text, "no interaction is open")
            begun, obj, behaviour = open_interaction
            if names and names != [obj.name, behaviour]:
                raise problem(time, text, f"the open interaction is {obj.name!r} {behaviour!r}")
            obj.interactions.append(InteractionPlan(behaviour, Window(begun, time)))
            open_interaction = None
        else:
            raise problem(time, text, "not a marker (scene | look <object> | begin <object> <behaviour> | end)")
    if open_interaction is not None and cut:
        begun, obj, behaviour = open_interaction
        obj.interactions.append(InteractionPlan(behaviour, Window(begun, stop)))
    elif open_interaction is not None:
        raise problem(open_interaction[0], "begin", "the recording ends before its end marker")
    _close_scene_windows(scenes, stop)
    return [scene for scene in scenes if scene.objects]


def _close_scene_windows(scenes: list[ScenePlan], stop: int) -> None:
    """A scene ends where the next one starts (or with the recording)."""
    for scene, following in zip(scenes, [*scenes[1:], None], strict=True):
        scene.window = Window(scene.window.start, stop if following is None else following.window.start - 1)


def plan_from_windows(schedule: Windows, start: int, stop: int) -> list[ScenePlan]:
    """Scenes from a fixed schedule; objects are named ``object_<n>`` and only complete objects are kept."""
    look = round(schedule.look * NANOSECONDS)
    interaction = round(schedule.interaction * NANOSECONDS)
    span = look + interaction * len(schedule.behaviours)
    first = start + round(schedule.start * NANOSECONDS)
    count = max(0, (stop - first + 1) // span)
    scenes: list[ScenePlan] = []
    for number in range(count):
        begin = first + number * span
        if number % schedule.objects_per_scene == 0:
            scene_stop = min(stop, begin + span * schedule.objects_per_scene - 1)
            scenes.append(ScenePlan(len(scenes), Window(begin, scene_stop)))
        obj = ObjectPlan(f"object_{number}", Window(begin, begin + look - 1))
        for position, behaviour in enumerate(schedule.behaviours):
            window_start = begin + look + position * interaction
            obj.interactions.append(InteractionPlan(behaviour, Window(window_start, window_start + interaction - 1)))
        scenes[-1].objects.append(obj)
    return scenes


def finger_series(
    joint_times: Sequence[int], angles: Sequence[float], touch_times: Sequence[int], pressures: Sequence[float]
) -> tuple[np.ndarray, np.ndarray]:
    """Haptic and proprioceptive series: one sample per joint reading, the haptic value linearly
    interpolated at its instant.

    A tactile sensor and the joint encoders are rarely sampled together;
    interpolating the haptic series onto the joint's clock keeps the joint's
    own samples exact (``numpy.interp`` holds the end values outside the
    haptic readings' span).
    """
    haptic = np.interp(np.asarray(joint_times, dtype=np.float64), np.asarray(touch_times, dtype=np.float64), pressures)
    return haptic, np.asarray(angles, dtype=np.float64)
