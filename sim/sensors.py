"""Simulated iCub sensors: the raw payloads a robot bridge sends (§II-C).

One object is an :class:`ObjectBody`, a shape primitive sized by its adjectives;
:func:`record_object` runs the paper's data-collection protocol on it (§II-C,
steps 1-3.5): a first Kinect look, then for every applicable behaviour a fresh
placement, a cloud before, the behaviour, a cloud after, with the index-finger
series during *grasp* and the audio during *shake*.

Every modelling choice is documented in ``docs/world.md``; the constants below
are the simulator's physics, named so that a reader can change one at a time.
Geometry is sampled with vectorised numpy (area-uniform surface points, then a
camera-visibility cull), so that recording the paper's 60 objects (about 1,300
clouds) stays cheap (the figure: docs/benchmarks.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import signal

from core.errors import InvalidInputError
from core.payloads import Audio, FingerSeries, Interaction, ObjectRecording, PointCloud

#: Shape primitives a noun can be rendered as.
PRIMITIVES: tuple[str, ...] = ("box", "ball", "cylinder", "cup", "plate", "tool")

#: The physical effect a behaviour has; ``BehaviourEffect.kind`` is one of these.
EFFECT_KINDS: tuple[str, ...] = ("lift", "slide", "drop", "throw", "knock_down", "shake")

#: The adjective pairs the simulator renders, each a physical property (stiffness,
#: sound, height, width, surface curvature). Other pairs may exist in a world's
#: vocabulary; they do not change the payloads.
RENDERED_ADJECTIVE_PAIRS: tuple[tuple[str, str], ...] = (
    ("hard", "soft"),
    ("noisy", "silent"),
    ("tall", "short"),
    ("thin", "thick"),
    ("round", "edgy"),
)

# Kinect in front of and above the table, looking at the workspace (metres, table frame).
CAMERA_POSITION = np.array([0.0, -0.55, 0.75])
# Where a supervisor places an object (step 1 and 3.5 of §II-C), and its yaw spread.
PLACEMENT_X = (-0.15, 0.15)
PLACEMENT_Y = (0.20, 0.40)
PLACEMENT_YAW = math.radians(45.0)
# Points per m² of visible surface after the usual voxel down-sampling, and the cloud size bounds.
POINT_DENSITY = 150_000.0
MIN_POINTS = 2_000
MAX_POINTS = 5_000
# Table-plane segmentation removes everything this close to the table.
TABLE_CUT = 0.004
# Kinect (v1) depth error along the viewing ray: random noise and the disparity quantisation
# step both grow with the squared distance d (Khoshelham & Elberink 2012: sigma ~ 1.4 mm * d^2,
# step ~ 2.9 mm * d^2, d in metres); about 2 and 3.5 mm at this camera's 1.1 m range.
DEPTH_NOISE_BASE = 0.0005
DEPTH_NOISE_PER_M2 = 0.0014
DEPTH_STEP_PER_M2 = 0.0029
# Holes: specular or IR-absorbing patches return no depth; up to HOLES_MAX per snapshot.
HOLE_RATE = 0.6
HOLES_MAX = 2
HOLE_RADIUS = (0.008, 0.02)
# An upright object tips over (knock down, or when dropped/thrown) if its height exceeds this
# multiple of its narrower footprint side.
TOPPLE_ASPECT = 1.25
CUP_WALL = 0.004
CUP_BOTTOM = 0.006
CUP_HANDLE_TUBE = 0.005

AUDIO_SAMPLE_RATE = 16_000
AUDIO_SECONDS = 1.0
# Peak amplitude of a hard object's knock against the fingers (scaled by its stiffness).
HANDLING_KNOCK = 0.03
FINGER_SAMPLES = 100
HAPTIC_FULL_SCALE = 255.0


@dataclass(frozen=True)
class _SizeRanges:
    """Uniform ranges (metres) of the width (thin/thick) and height (tall/short) parameters."""

    thin: tuple[float, float]
    thick: tuple[float, float]
    short: tuple[float, float]
    tall: tuple[float, float]


# Labels are human judgements relative to the object set, so the two ranges of a pair overlap a
# little at the boundary (about 5.5-6 cm wide, 10.5-12 cm tall) whatever the primitive: one
# adjective prototype fits every noun, but not perfectly (§II-A). A plate's "short" range is the
# height of its dish (it lies flat); its "tall" range is a standing plate's diameter.
_SIZES: dict[str, _SizeRanges] = {
    "box": _SizeRanges(thin=(0.035, 0.06), thick=(0.055, 0.16), short=(0.04, 0.115), tall=(0.105, 0.22)),
    "ball": _SizeRanges(thin=(0.040, 0.06), thick=(0.055, 0.11), short=(0.04, 0.115), tall=(0.105, 0.20)),
    "cylinder": _SizeRanges(thin=(0.035, 0.06), thick=(0.055, 0.10), short=(0.06, 0.12), tall=(0.105, 0.22)),
    "cup": _SizeRanges(thin=(0.045, 0.06), thick=(0.055, 0.095), short=(0.07, 0.115), tall=(0.105, 0.18)),
    "plate": _SizeRanges(thin=(0.045, 0.06), thick=(0.13, 0.22), short=(0.018, 0.03), tall=(0.12, 0.22)),
    "tool": _SizeRanges(thin=(0.040, 0.06), thick=(0.055, 0.13), short=(0.07, 0.115), tall=(0.12, 0.22)),
}
# Materials, overlapping at the boundary for the same reason: stiffness in [0, 1] (hard / soft),
# the rattle's peak amplitude (noisy: log-uniform; silent: a faint one at most).
_STIFFNESS = {"hard": (0.55, 1.0), "soft": (0.1, 0.65)}
_NOISY_LOUDNESS = (0.02, 0.4)
_SILENT_LOUDNESS = (0.0, 0.004)


@dataclass(frozen=True)
class Difficulty:
    """How hard a world is to perceive: the knobs that make nouns and adjectives overlap
    (docs/world.md, "Difficulty"). The defaults are the ``easy`` world, bit for bit.

    Adjectives: ``adjective_overlap`` extends each adjective's range of its physical
    parameter (width, height, stiffness, rattle loudness) by that fraction of the
    distance to the far end of its partner's range, so the two overlap (0: the easy
    ranges); ``roundness_overlap`` makes round/edgy graded: a prism-like body's corner
    radius is a fraction ρ of its half-width, ρ ∈ [1 - x, 1] when round and
    [0, 0.2 + x] when edgy (0: round bodies are fully round, the easy rule).
    Nouns: ``handle_probability`` of a cup; ``depth_noise_scale`` multiplies the
    Kinect's random depth error; an occluder in front hides, with
    ``occlusion_probability`` per snapshot, a share U(0, ``occlusion_fraction``) of the
    cloud from a random side (a partial view); ``lying_probability`` is the chance that
    the supervisor puts the object down on its side for the first look (pose).
    """

    name: str = "easy"
    adjective_overlap: float = 0.0
    roundness_overlap: float = 0.0
    handle_probability: float = 0.75
    depth_noise_scale: float = 1.0
    occlusion_probability: float = 0.0
    occlusion_fraction: float = 0.0
    lying_probability: float = 0.0

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            if name == "name":
                continue
            value = getattr(self, name)
            top = math.inf if name == "depth_noise_scale" else 1.0
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= top:
                raise InvalidInputError(f"difficulty.{name}", f"must be a number in [0, {top}], got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Difficulty:
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise InvalidInputError("difficulty", f"unknown fields {sorted(unknown)}")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: The easy world's difficulty: every knob at the value the simulator had before worlds had one.
EASY = Difficulty()


def _overlapping(
    low: tuple[float, float], high: tuple[float, float], overlap: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The ranges of a pair's lower and higher adjective, each extended towards the other by
    ``overlap`` times the distance to the far end of the other's range (unchanged at 0)."""
    if overlap == 0.0:
        return low, high
    return (low[0], low[1] + overlap * (high[1] - low[1])), (high[0] - overlap * (high[0] - low[0]), high[1])


@dataclass(frozen=True)
class BehaviourEffect:
    """What a behaviour does to an object's pose: a world parameter the planner learns back (§V-E).

    ``direction`` is a unit vector on the table (x right, y forward); ``distance``
    the mean displacement along it (m); ``spread`` the standard deviation of the
    displacement (m); ``yaw_spread`` of the yaw change (rad); ``topple_probability``
    the chance that an object slender enough to tip (see ``TOPPLE_ASPECT``) ends on its side.
    """

    kind: str
    direction: tuple[float, float] = (0.0, 0.0)
    distance: float = 0.0
    spread: float = 0.0
    yaw_spread: float = 0.0
    topple_probability: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in EFFECT_KINDS:
            raise InvalidInputError("behaviour_effect.kind", f"{self.kind!r} is not one of {EFFECT_KINDS}")
        direction = tuple(float(v) for v in self.direction)
        if len(direction) != 2 or not all(math.isfinite(v) for v in direction):
            raise InvalidInputError("behaviour_effect.direction", f"must be two finite numbers, got {self.direction!r}")
        norm = math.hypot(*direction)
        if self.kind in ("slide", "throw", "knock_down") and norm == 0.0:
            raise InvalidInputError("behaviour_effect.direction", f"a {self.kind} needs a non-zero direction")
        object.__setattr__(self, "direction", tuple(v / norm for v in direction) if norm else (0.0, 0.0))
        for name in ("distance", "spread", "yaw_spread"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidInputError(f"behaviour_effect.{name}", f"must be a finite number >= 0, got {value!r}")
            object.__setattr__(self, name, value)
        if not 0.0 <= float(self.topple_probability) <= 1.0:
            raise InvalidInputError(
                "behaviour_effect.topple_probability", f"{self.topple_probability!r} is not in [0, 1]"
            )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BehaviourEffect:
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise InvalidInputError("behaviour_effect", f"unknown fields {sorted(unknown)}")
        if "kind" not in data:
            raise InvalidInputError("behaviour_effect.kind", "is required")
        return cls(**{**data, "direction": tuple(data.get("direction", (0.0, 0.0)))})

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["direction"] = list(self.direction)
        return out


@dataclass(frozen=True)
class ObjectBody:
    """The physical object behind a concept label: fixed for the object, whatever is recorded.

    ``width``, ``depth`` and ``height`` are the primitive's own dimensions in metres
    (a plate's are its diameter, diameter and dish height; a tool's depth is its
    head's diameter). A ``rounded`` body has fully rounded cross-sections; an edgy
    one has sharp edges bevelled by ``edge_radius``. ``stiffness`` in [0, 1]
    drives the finger series, ``loudness`` (peak amplitude of the rattle) and
    ``rattle_hz`` (its centre frequency) the audio. Shape details of one primitive:
    ``lean`` (a standing plate's backward lean, rad; 0 for a plate lying flat),
    ``has_handle`` (a cup), ``handle_radius`` and ``handle_offset`` (a tool's handle
    and its position along the head, m).
    """

    primitive: str
    width: float
    depth: float
    height: float
    rounded: bool
    stiffness: float
    loudness: float
    rattle_hz: float
    edge_radius: float = 0.0
    lean: float = 0.0
    has_handle: bool = False
    handle_radius: float = 0.0
    handle_offset: float = 0.0

    @property
    def standing(self) -> bool:
        """A plate standing in a rack (a *tall* plate) rather than lying flat."""
        return self.primitive == "plate" and self.lean > 0.0

    def section(self, a: float, b: float) -> tuple[float, float, float]:
        """A cross-section of half-sizes a, b with this body's corner radius."""
        return a, b, (min(a, b) if self.rounded else min(self.edge_radius, min(a, b)))

    @property
    def upright_extent(self) -> tuple[float, float, float]:
        """Bounding box (width, depth, height) of the object standing as placed, before any yaw."""
        if self.standing:
            cos, sin = math.cos(self.lean), math.sin(self.lean)
            return self.width, self.width * sin + self.height * cos, self.width * cos + self.height * sin
        if self.primitive == "cup" and self.has_handle:
            return self.width + _cup_handle_ring(self) + CUP_HANDLE_TUBE, self.depth, self.height
        return self.width, self.depth, self.height

    @property
    def can_topple(self) -> bool:
        width, depth, height = self.upright_extent
        return height > TOPPLE_ASPECT * min(width, depth)

    @property
    def grip_width(self) -> float:
        """The span the index finger closes on: a plate's rim, a tool's handle, otherwise the body."""
        if self.primitive == "plate":
            return self.height
        if self.primitive == "tool":
            return 2.0 * self.handle_radius
        return min(self.width, self.depth)


@dataclass(frozen=True)
class Pose:
    """Where the object rests: footprint centre (x, y) in metres, yaw in radians, and, when it
    lies on its side, the heading (radians) towards which its top fell."""

    x: float
    y: float
    yaw: float
    tip_heading: float | None = None


def _adjective_values(adjectives: Collection[str]) -> dict[str, bool]:
    """For each rendered pair, whether the object carries the pair's first adjective."""
    present = set(adjectives)
    values: dict[str, bool] = {}
    for first, second in RENDERED_ADJECTIVE_PAIRS:
        if (first in present) == (second in present):
            raise InvalidInputError("adjectives", f"needs exactly one of {first!r} / {second!r}, got {sorted(present)}")
        values[first] = first in present
    return values


def make_body(
    primitive: str, adjectives: Collection[str], rng: np.random.Generator, difficulty: Difficulty = EASY
) -> ObjectBody:
    """Draw a physical object of a primitive whose dimensions and materials follow its adjectives.

    Within a noun, real objects vary (Fig. 3): edgy bodies have their edges bevelled
    (radius up to a tenth of the smaller side), soft balls are squashed by up to 20 %, a quarter of the cups
    have no handle, a tool's handle sits anywhere along its head (mallet to hammer),
    and a standing plate leans back by 8-25 degrees. ``difficulty`` widens the adjectives'
    ranges into each other and grades round/edgy (:class:`Difficulty`).
    """
    if primitive not in _SIZES:
        raise InvalidInputError("primitive", f"{primitive!r} is not one of {PRIMITIVES}")
    has = _adjective_values(adjectives)
    sizes = _SIZES[primitive]
    overlap = difficulty.adjective_overlap
    thin, thick = _overlapping(sizes.thin, sizes.thick, overlap)
    # A plate's two height ranges are different things (a dish's height, a standing plate's diameter).
    short, tall = _overlapping(sizes.short, sizes.tall, 0.0 if primitive == "plate" else overlap)
    width = float(rng.uniform(*(thin if has["thin"] else thick)))
    height = float(rng.uniform(*(tall if has["tall"] else short)))
    shape: dict[str, Any] = {"depth": width, "edge_radius": float(rng.uniform(0.0, 0.2)) * 0.5 * width}
    if primitive == "box":
        shape["depth"] = width * float(rng.uniform(0.55, 1.0))
        shape["edge_radius"] = float(rng.uniform(0.0, 0.2)) * 0.5 * shape["depth"]
    elif primitive == "ball":
        # As spherical as the height range allows, then squashed a little (more if soft).
        low, high = tall if has["tall"] else short
        height = min(max(width, low), high) * float(rng.uniform(0.97, 1.0) if has["hard"] else rng.uniform(0.8, 1.0))
    elif primitive == "plate":
        # A tall plate stands in a rack (its diameter then also fills the height range); a short one lies flat.
        if has["tall"]:
            width = max(width, height)
            shape.update(depth=width, lean=math.radians(float(rng.uniform(8.0, 25.0))))
        height = float(rng.uniform(*sizes.short))
    elif primitive == "cup":
        shape["has_handle"] = bool(rng.random() < difficulty.handle_probability)
    elif primitive == "tool":
        head_radius = float(rng.uniform(0.018, 0.026))
        handle_radius = float(rng.uniform(0.010, 0.014))
        shape.update(
            depth=2.0 * head_radius,
            edge_radius=float(rng.uniform(0.0, 0.004)),
            handle_radius=handle_radius,
            handle_offset=float(rng.uniform(-0.5, 0.5)) * max(width / 2 - handle_radius, 0.0),
        )
    if difficulty.roundness_overlap > 0.0 and primitive in ("box", "cylinder", "cup"):
        # Graded roundness: the corner radius as a fraction of the half-width, overlapping between the labels.
        graded = difficulty.roundness_overlap
        fraction = rng.uniform(1.0 - graded, 1.0) if has["round"] else rng.uniform(0.0, min(0.2 + graded, 1.0))
        shape["edge_radius"] = float(fraction) * 0.5 * min(width, shape["depth"])
        rounded = False
    else:
        rounded = has["round"]
    soft, hard = _overlapping(_STIFFNESS["soft"], _STIFFNESS["hard"], overlap)
    stiffness = float(rng.uniform(*(hard if has["hard"] else soft)))
    silent, noisy = _loudness_ranges(overlap)
    if has["noisy"]:
        loudness = float(np.exp(rng.uniform(np.log(noisy[0]), np.log(noisy[1]))))
    else:
        loudness = float(rng.uniform(*silent))
    return ObjectBody(
        primitive=primitive,
        width=width,
        height=height,
        rounded=rounded,
        stiffness=stiffness,
        loudness=loudness,
        rattle_hz=float(rng.uniform(1500.0, 5000.0)),
        **shape,
    )


def _loudness_ranges(overlap: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The silent and noisy ranges of the rattle's loudness, overlapped on a log scale (a decade
    below the silent maximum stands for the silent range's far end, since its floor is 0)."""
    if overlap == 0.0:
        return _SILENT_LOUDNESS, _NOISY_LOUDNESS
    top = math.log(_SILENT_LOUDNESS[1])
    (_, silent_top), (noisy_low, noisy_high) = _overlapping(
        (top - math.log(10.0), top), (math.log(_NOISY_LOUDNESS[0]), math.log(_NOISY_LOUDNESS[1])), overlap
    )
    return (0.0, math.exp(silent_top)), (math.exp(noisy_low), math.exp(noisy_high))


# --- surface sampling: every patch gives area-uniform points with outward normals -------------------
# Surfaces are sampled as (3, n) arrays: rows x, y, z, so that every per-axis operation and
# reduction runs over contiguous memory (several times faster than (n, 3) columns).
_Sample = tuple[np.ndarray, np.ndarray, np.ndarray]  # points (3, n), outward normals (3, n), interior flags (n,)
_RoundedRect = tuple[float, float, float]  # half-width a, half-depth b, corner radius r


class _Patch(NamedTuple):
    """A piece of surface: its area, an area-uniform sampler, and its normal when it is flat (in the body frame)."""

    area: float
    sample: Callable[[int, np.random.Generator], _Sample]
    flat_normal: tuple[float, float, float] | None = None


def _rounded_rect_area(a: float, b: float, r: float) -> float:
    return 4.0 * a * b - (4.0 - math.pi) * r * r


_SIDE_NORMALS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))


def _inside_rounded_rect(x: np.ndarray, y: np.ndarray, a: float, b: float, r: float) -> np.ndarray:
    ax, ay = np.abs(x), np.abs(y)
    dx, dy = ax - (a - r), ay - (b - r)
    in_corner_box = (dx > 0) & (dy > 0)
    return (ax <= a) & (ay <= b) & ~(in_corner_box & (dx * dx + dy * dy > r * r))


def _uniform_in_rounded_rect(
    shape: _RoundedRect, n: int, rng: np.random.Generator, hole: _RoundedRect | None = None
) -> np.ndarray:
    """(2, n) points uniform inside a rounded rectangle, minus an optional concentric rounded-rectangle hole."""
    a, b, r = shape
    found: list[np.ndarray] = []
    count = 0
    while count < n:
        m = int(1.4 * (n - count)) + 16
        x, y = rng.uniform(-a, a, m), rng.uniform(-b, b, m)
        keep = _inside_rounded_rect(x, y, a, b, r)
        if hole is not None:
            keep &= ~_inside_rounded_rect(x, y, *hole)
        found.append(np.stack([x[keep], y[keep]]))
        count += found[-1].shape[1]
    return np.concatenate(found, axis=1)[:, :n]


def _walls(shape: _RoundedRect, z0: float, z1: float, inward: bool = False) -> list[_Patch]:
    """The vertical wall of a prism with a rounded-rectangle section, between heights z0 and z1:
    its four flat sides (so that those facing away from the camera are not sampled at all) and its
    four rounded corners, which together make one quarter-circle each. ``inward`` walls (a cup's
    inside) have their normals reversed and count as interior."""
    a, b, r = shape
    sign = -1.0 if inward else 1.0
    patches = []
    for k, (nx, ny) in enumerate(_SIDE_NORMALS):
        offset, half = (a, b - r) if k % 2 == 0 else (b, a - r)
        if half <= 0.0:
            continue

        def side(
            n: int, rng: np.random.Generator, nx: float = nx, ny: float = ny, offset: float = offset, half: float = half
        ) -> _Sample:
            along = rng.uniform(-half, half, n)
            points = np.stack([nx * offset - ny * along, ny * offset + nx * along, rng.uniform(z0, z1, n)])
            normals = np.zeros((3, n))
            normals[0], normals[1] = sign * nx, sign * ny
            return points, normals, np.full(n, inward)

        patches.append(_Patch(2 * half * (z1 - z0), side, (sign * nx, sign * ny, 0.0)))
    if r > 0.0:

        def corners(n: int, rng: np.random.Generator) -> _Sample:
            angle = rng.uniform(-math.pi, math.pi, n)
            cos, sin = np.cos(angle), np.sin(angle)
            points = np.stack(
                [np.sign(cos) * (a - r) + r * cos, np.sign(sin) * (b - r) + r * sin, rng.uniform(z0, z1, n)]
            )
            return points, sign * np.stack([cos, sin, np.zeros(n)]), np.full(n, inward)

        patches.append(_Patch(2.0 * math.pi * r * (z1 - z0), corners))
    return patches


def _cap(shape: _RoundedRect, z: float, up: bool, hole: _RoundedRect | None = None, interior: bool = False) -> _Patch:
    def sample(n: int, rng: np.random.Generator) -> _Sample:
        xy = _uniform_in_rounded_rect(shape, n, rng, hole)
        normals = np.zeros((3, n))
        normals[2] = 1.0 if up else -1.0
        return np.vstack([xy, np.full(n, z)]), normals, np.full(n, interior)

    area = _rounded_rect_area(*shape) - (_rounded_rect_area(*hole) if hole else 0.0)
    return _Patch(area, sample, (0.0, 0.0, 1.0 if up else -1.0))


def _spheroid(a: float, c: float) -> _Patch:
    """A spheroid with horizontal semi-axis a and vertical semi-axis c, resting on the table."""
    semi_axes = np.array([[a], [a], [c]])

    def sample(n: int, rng: np.random.Generator) -> _Sample:
        found: list[np.ndarray] = []
        count = 0
        while count < n:
            u = rng.standard_normal((3, int(1.3 * (n - count)) + 16))
            u /= np.sqrt((u * u).sum(axis=0))
            # Keep a direction with probability proportional to the area element of the map
            # sphere -> spheroid (|u / semi_axes|, maximal at 1 / min(a, c)).
            grad = u / semi_axes
            keep = rng.random(u.shape[1]) < np.sqrt((grad * grad).sum(axis=0)) * min(a, c)
            found.append(u[:, keep])
            count += found[-1].shape[1]
        u = np.concatenate(found, axis=1)[:, :n]
        normals = u / semi_axes
        normals /= np.sqrt((normals * normals).sum(axis=0))
        return u * semi_axes + np.array([[0.0], [0.0], [c]]), normals, np.zeros(n, dtype=bool)

    return _Patch(_spheroid_area(a, c), sample)


def _spheroid_area(a: float, c: float) -> float:
    """Surface area of a spheroid with equatorial semi-axis a and polar semi-axis c."""
    if abs(a - c) < 1e-9 * a:
        return 4.0 * math.pi * a * a
    if c < a:
        e = math.sqrt(1.0 - c * c / (a * a))
        return 2.0 * math.pi * a * a * (1.0 + (1.0 - e * e) / e * math.atanh(e))
    e = math.sqrt(1.0 - a * a / (c * c))
    return 2.0 * math.pi * a * a * (1.0 + c / (a * e) * math.asin(e))


def _cup_handle_ring(body: ObjectBody) -> float:
    return min(0.028, 0.3 * body.height)


def _cup_handle(body: ObjectBody) -> _Patch:
    """Half a torus on the +x side of the cup body (the handle), in the xz plane."""
    ring, tube = _cup_handle_ring(body), CUP_HANDLE_TUBE
    centre = np.array([[body.width / 2], [0.0], [0.55 * body.height]])

    def sample(n: int, rng: np.random.Generator) -> _Sample:
        found: list[np.ndarray] = []
        count = 0
        while count < n:
            m = int(1.3 * (n - count)) + 16
            phi, psi = rng.uniform(-math.pi / 2, math.pi / 2, m), rng.uniform(-math.pi, math.pi, m)
            # Area element of a torus grows with the distance from its axis, ring + tube * cos(psi).
            keep = rng.random(m) < (ring + tube * np.cos(psi)) / (ring + tube)
            found.append(np.stack([phi[keep], psi[keep]]))
            count += found[-1].shape[1]
        phi, psi = np.concatenate(found, axis=1)[:, :n]
        radial = np.stack([np.cos(phi), np.zeros(n), np.sin(phi)])
        normals = np.cos(psi) * radial
        normals[1] = np.sin(psi)
        return centre + ring * radial + tube * normals, normals, np.zeros(n, dtype=bool)

    return _Patch(2.0 * math.pi * tube * math.pi * ring, sample)


def _dish(shape: _RoundedRect, base: float, sag: float, rounded: bool) -> _Patch:
    """A plate's upper face: z = base + sag * rho^2, rho the normalised radius (Euclidean for a
    round plate, the max-norm for a square, edgy one), so it rises towards the rim."""
    radius = shape[0]

    def sample(n: int, rng: np.random.Generator) -> _Sample:
        x, y = _uniform_in_rounded_rect(shape, n, rng)
        if rounded:
            slope_x, slope_y = x, y
        else:
            along_x = np.abs(x) >= np.abs(y)
            slope_x, slope_y = np.where(along_x, x, 0.0), np.where(along_x, 0.0, y)
        z = base + sag * (slope_x**2 + slope_y**2) / radius**2
        normals = np.stack([-2.0 * sag * slope_x / radius**2, -2.0 * sag * slope_y / radius**2, np.ones(n)])
        normals /= np.sqrt((normals * normals).sum(axis=0))
        return np.stack([x, y, z]), normals, np.zeros(n, dtype=bool)

    return _Patch(_rounded_rect_area(*shape), sample)


def _along_x(patch: _Patch, lift: float) -> _Patch:
    """Turn a patch built around the z axis into one around the x axis, raised by ``lift``."""

    def sample(n: int, rng: np.random.Generator) -> _Sample:
        points, normals, interior = patch.sample(n, rng)
        points = points[[2, 0, 1]]
        points[2] += lift
        return points, normals[[2, 0, 1]], interior

    normal = patch.flat_normal
    return _Patch(patch.area, sample, None if normal is None else (normal[2], normal[0], normal[1]))


def _prism(shape: _RoundedRect, height: float) -> list[_Patch]:
    return [*_walls(shape, 0.0, height), _cap(shape, height, up=True), _cap(shape, 0.0, up=False)]


def _shifted_x(patch: _Patch, shift: float) -> _Patch:
    def sample(n: int, rng: np.random.Generator) -> _Sample:
        points, normals, interior = patch.sample(n, rng)
        points[0] += shift
        return points, normals, interior

    return _Patch(patch.area, sample, patch.flat_normal)


def _cup_inside(body: ObjectBody) -> _RoundedRect:
    return body.section(body.width / 2 - CUP_WALL, body.depth / 2 - CUP_WALL)


def _patches(body: ObjectBody) -> list[_Patch]:
    """The surface of a body in its own upright frame (footprint centred on the origin, table at z = 0)."""
    a, b, h = body.width / 2, body.depth / 2, body.height
    outline = body.section(a, b)
    if body.primitive in ("box", "cylinder") or (body.primitive == "ball" and not body.rounded):
        return _prism(outline, h)
    if body.primitive == "ball":
        return [_spheroid(a, h / 2)]
    if body.primitive == "cup":
        inside = _cup_inside(body)
        return [
            *_walls(outline, 0.0, h),
            *_walls(inside, CUP_BOTTOM, h, inward=True),
            _cap(inside, CUP_BOTTOM, up=True, interior=True),
            _cap(outline, h, up=True, hole=inside),
            _cap(outline, 0.0, up=False),
        ] + ([_cup_handle(body)] if body.has_handle else [])
    if body.primitive == "plate":
        rim = 0.35 * h
        return [_dish(outline, rim, h - rim, body.rounded), *_walls(outline, 0.0, h), _cap(outline, 0.0, up=False)]
    head = body.depth / 2
    head_section = body.section(head, head)
    handle_section = body.section(body.handle_radius, body.handle_radius)
    head_patches = [*_walls(head_section, -a, a), _cap(head_section, a, up=True), _cap(head_section, -a, up=False)]
    handle_patches = [*_walls(handle_section, 2 * head, h), _cap(handle_section, h, up=True)]
    return [_along_x(patch, head) for patch in head_patches] + [
        _shifted_x(patch, body.handle_offset) for patch in handle_patches
    ]


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotation_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _tip_rotation(heading: float) -> np.ndarray:
    """A quarter turn about the horizontal axis z x h, which lays the object's top towards heading h."""
    kx, ky = -math.sin(heading), math.cos(heading)
    k = np.array([[0.0, 0.0, ky], [0.0, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + k + k @ k


def _body_rotation(body: ObjectBody, pose: Pose) -> np.ndarray:
    rotation = _rotation_z(pose.yaw)
    if body.standing:
        # Face towards the robot (-y), leaning back by the plate's lean.
        rotation = rotation @ _rotation_x(math.pi / 2 - body.lean)
    if pose.tip_heading is not None:
        rotation = _tip_rotation(pose.tip_heading) @ rotation
    return rotation


def _facing_camera(patches: list[_Patch], rotation: np.ndarray, pose: Pose) -> list[_Patch]:
    """Drop the flat patches that surely face away from the camera.

    Seen from the camera (about 1 m away), no point of an object (< 0.15 m from its
    footprint centre) is more than ~10 degrees off the direction to that centre, so a
    flat patch whose normal makes a cosine below -0.3 with it is entirely back-facing.
    """
    towards = CAMERA_POSITION - np.array([pose.x, pose.y, 0.1])
    towards /= np.linalg.norm(towards)
    return [p for p in patches if p.flat_normal is None or float(towards @ (rotation @ p.flat_normal)) > -0.3]


def _sample_surface(patches: list[_Patch], n: int, rng: np.random.Generator) -> _Sample:
    areas = np.array([patch.area for patch in patches])
    counts = rng.multinomial(n, areas / areas.sum())
    parts = [patch.sample(int(k), rng) for patch, k in zip(patches, counts, strict=True) if k > 0]
    points, normals, interior = zip(*parts, strict=True)
    return np.concatenate(points, axis=1), np.concatenate(normals, axis=1), np.concatenate(interior)


def _visible(
    points: np.ndarray, normals: np.ndarray, interior: np.ndarray, camera_local: np.ndarray, body: ObjectBody
) -> np.ndarray:
    """Back-face culling in the body's frame; a cup's inside is seen only along rays that leave through
    its opening (the one self-occlusion modelled: handles are small)."""
    visible = (normals * (camera_local[:, None] - points)).sum(axis=0) > 0.0
    if interior.any():
        top = body.height
        if camera_local[2] <= top:
            return visible & ~interior
        p = points[:, interior]
        t = (top - p[2]) / (camera_local[2] - p[2])
        exit_x, exit_y = p[:2] + t * (camera_local[:2, None] - p[:2])
        visible[interior] &= _inside_rounded_rect(exit_x, exit_y, *_cup_inside(body))
    return visible


def point_cloud(body: ObjectBody, pose: Pose, rng: np.random.Generator, difficulty: Difficulty = EASY) -> PointCloud:
    """One Kinect snapshot of the body at a pose: only its camera-visible side, with sensor noise.

    Surface points are drawn area-uniformly, culled to what the camera sees, holed
    where the sensor returns nothing, and ``POINT_DENSITY`` per m² of the visible
    area are kept (between ``MIN_POINTS`` and ``MAX_POINTS``), so bigger objects
    give bigger clouds, as a down-sampled Kinect segment does. ``difficulty`` scales the
    depth noise and may hide part of the cloud (:class:`Difficulty`).
    """
    rotation = _body_rotation(body, pose)
    patches = _facing_camera(_patches(body), rotation, pose)
    total_area = sum(patch.area for patch in patches)
    # A front-facing flat patch is seen almost whole, a curved one about half: this sizes the first batch.
    first_guess = sum(patch.area * (0.9 if patch.flat_normal else 0.45) for patch in patches) / total_area
    density = POINT_DENSITY * float(rng.uniform(0.9, 1.1))
    kept: list[np.ndarray] = []
    kept_count, drawn = 0, 0
    target = _points_for(first_guess * total_area, density)
    offset = np.zeros(3)
    holes = np.zeros((0, 4))
    while kept_count < target:
        # Later batches make up the shortfall at the visible fraction measured so far.
        expected_fraction = kept_count / drawn if kept_count else first_guess / 4 ** len(kept)
        batch = int(1.15 * (target - kept_count) / expected_fraction) + 64
        points, normals, interior = _sample_surface(patches, batch, rng)
        world = rotation @ points
        if drawn == 0:
            # Rest on the table, footprint centred on the pose (the same offset for every batch of this snapshot).
            low, high = world.min(axis=1), world.max(axis=1)
            offset = np.array([pose.x - (low[0] + high[0]) / 2, pose.y - (low[1] + high[1]) / 2, -low[2]])
        world += offset[:, None]
        camera_local = rotation.T @ (CAMERA_POSITION - offset)
        mask = _visible(points, normals, interior, camera_local, body) & (world[2] > TABLE_CUT)
        if drawn == 0:
            holes = _holes(world[:, mask], rng)
        for x, y, z, radius in holes:
            mask &= (world[0] - x) ** 2 + (world[1] - y) ** 2 + (world[2] - z) ** 2 > radius**2
        kept.append(world[:, mask])
        kept_count += kept[-1].shape[1]
        drawn += batch
        if len(kept) == 1:
            target = _points_for(total_area * kept_count / drawn, density)
    cloud = np.concatenate(kept, axis=1)
    cloud = cloud[:, rng.choice(cloud.shape[1], size=target, replace=False)]
    if difficulty.occlusion_probability > 0.0 and rng.random() < difficulty.occlusion_probability:
        cloud = _occluded(cloud, float(rng.uniform(0.0, difficulty.occlusion_fraction)), rng)
    return PointCloud(_kinect_noise(cloud, rng, difficulty.depth_noise_scale).T)


def _occluded(cloud: np.ndarray, hidden: float, rng: np.random.Generator) -> np.ndarray:
    """The cloud ((3, n)) without the ``hidden`` share of its points furthest along a random direction
    of the camera's image plane (x, z): a partial view, cut off by an occluder or the segmentation."""
    angle = float(rng.uniform(-math.pi, math.pi))
    along = math.cos(angle) * cloud[0] + math.sin(angle) * cloud[2]
    return cloud[:, along <= np.quantile(along, 1.0 - hidden)]


def _points_for(visible_area: float, density: float) -> int:
    return int(np.clip(round(visible_area * density), MIN_POINTS, MAX_POINTS))


def _kinect_noise(points: np.ndarray, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """Depth along each viewing ray: random error, then quantised to the disparity step ((3, n) in and out).

    A structured-light sensor's error is overwhelmingly along the ray (its lateral
    error is below the 2 mm pixel footprint at this range), so only that is modelled. ``scale``
    multiplies the random error (a harder world's sensor), not the quantisation step.
    """
    ray = points - CAMERA_POSITION[:, None]
    distance = np.sqrt((ray * ray).sum(axis=0))
    sigma = (DEPTH_NOISE_BASE + DEPTH_NOISE_PER_M2 * distance**2) * scale
    noisy = distance + sigma * rng.standard_normal(distance.size)
    step = DEPTH_STEP_PER_M2 * distance**2
    measured = np.round(noisy / step) * step
    return CAMERA_POSITION[:, None] + ray * (measured / distance)


def _holes(visible: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Up to ``HOLES_MAX`` spheres (x, y, z, radius), centred on visible points, where no depth returns."""
    count = int(rng.binomial(HOLES_MAX, HOLE_RATE / HOLES_MAX)) if visible.shape[1] else 0
    centres = visible[:, rng.integers(0, max(visible.shape[1], 1), count)]
    return np.column_stack([centres.T, rng.uniform(*HOLE_RADIUS, count)])


def place(rng: np.random.Generator) -> Pose:
    """A supervisor's placement on the table (§II-C steps 1 and 3.5): upright, random position and yaw."""
    return Pose(
        x=float(rng.uniform(*PLACEMENT_X)),
        y=float(rng.uniform(*PLACEMENT_Y)),
        yaw=float(rng.uniform(-PLACEMENT_YAW, PLACEMENT_YAW)),
    )


def apply_behaviour(body: ObjectBody, pose: Pose, effect: BehaviourEffect, rng: np.random.Generator) -> Pose:
    """The pose after a behaviour: a noisy displacement along its direction, a yaw change, maybe a fall."""
    direction = np.array(effect.direction)
    across = np.array([-direction[1], direction[0]])
    heading = math.atan2(direction[1], direction[0])
    tip: float | None = None
    if effect.kind in ("slide", "throw"):
        step = direction * (effect.distance + rng.normal(0.0, effect.spread)) + across * rng.normal(
            0.0, effect.spread / 2
        )
        if effect.kind == "throw" and body.can_topple and rng.random() < effect.topple_probability:
            tip = heading
    elif effect.kind == "knock_down":
        if body.can_topple and rng.random() < effect.topple_probability:
            # It falls over: the footprint centre moves by about half the height towards the push.
            tip = heading
            step = direction * (body.upright_extent[2] / 2 + rng.normal(0.0, effect.spread))
        else:
            step = direction * (effect.distance + rng.normal(0.0, effect.spread))
    else:
        step = rng.normal(0.0, effect.spread, 2) + direction * effect.distance
        if effect.kind == "drop" and body.can_topple and rng.random() < effect.topple_probability:
            tip = float(rng.uniform(-math.pi, math.pi))
    return Pose(
        x=pose.x + float(step[0]),
        y=pose.y + float(step[1]),
        yaw=pose.yaw + float(rng.normal(0.0, effect.yaw_spread)),
        tip_heading=tip,
    )


def handling_audio(body: ObjectBody, rng: np.random.Generator, shaking: bool = True) -> Audio:
    """One second of microphone audio while the object is shaken (or, ``shaking=False``, grasped and lifted).

    Every recording has room noise and the arm's motor hum, and every object knocks
    against the fingers once per reversal of the motion (a lift has two: up and
    down), louder the harder it is. A noisy object adds its rattle: a cluster of
    short, decaying broadband bursts after each reversal, as loose contents hit the walls.
    """
    n = int(AUDIO_SAMPLE_RATE * AUDIO_SECONDS)
    t = np.arange(n) / AUDIO_SAMPLE_RATE
    hum_hz = rng.uniform(90.0, 140.0)
    audio = rng.normal(0.0, 0.002, n) + 0.003 * (
        np.sin(2 * np.pi * hum_hz * t) + 0.5 * np.sin(2 * np.pi * 2 * hum_hz * t + rng.uniform(0, 2 * np.pi))
    )
    reversals = np.arange(1, 2 * int(rng.integers(3, 6)) + 1) if shaking else np.array([1, 3])
    reversal_times = reversals / (reversals[-1] + 1.0) * AUDIO_SECONDS
    impacts_per_reversal = rng.poisson(4.0, len(reversal_times)) + 1
    rattle_times = np.repeat(reversal_times, impacts_per_reversal) + rng.exponential(0.012, impacts_per_reversal.sum())
    times = np.concatenate([reversal_times, rattle_times])
    amplitudes = np.concatenate(
        [
            HANDLING_KNOCK * body.stiffness * rng.uniform(0.3, 1.0, len(reversal_times)),
            body.loudness * rng.lognormal(0.0, 0.4, len(rattle_times)),
        ]
    )
    impulses = np.zeros(n)
    np.add.at(impulses, np.minimum((times * AUDIO_SAMPLE_RATE).astype(int), n - 1), amplitudes)
    decay = math.exp(-1.0 / (rng.uniform(0.002, 0.006) * AUDIO_SAMPLE_RATE))
    envelope = signal.lfilter([1.0], [1.0, -decay], impulses)
    low, high = body.rattle_hz / 2, min(body.rattle_hz * 2, 0.45 * AUDIO_SAMPLE_RATE)
    band_b, band_a = signal.butter(2, [low, high], btype="band", fs=AUDIO_SAMPLE_RATE)
    carrier = rng.normal(size=n)
    bursts = envelope * (0.5 * carrier + 0.5 * signal.lfilter(band_b, band_a, carrier))
    return Audio(np.clip(audio + bursts, -1.0, 1.0).astype(np.float32), AUDIO_SAMPLE_RATE)


def grasp_finger_series(body: ObjectBody, rng: np.random.Generator) -> FingerSeries:
    """The index finger's tactile pressure (0-255 units) and joint angle (rad) over a one-second grasp.

    The finger closes at constant speed until it meets the object (earlier for a
    wider grip). A hard object stops it at once and the pressure jumps to a high
    plateau; a soft one yields, so the finger keeps closing and the pressure
    rises slowly to a lower plateau (time constant growing with compliance).
    """
    t = np.linspace(0.0, 1.0, FINGER_SAMPLES)
    open_angle, speed = 0.1, float(rng.uniform(2.2, 2.8))
    contact_angle = 0.15 + 1.2 * float(np.clip(1.0 - body.grip_width / 0.12, 0.05, 1.0)) + rng.normal(0.0, 0.02)
    contact_time = (contact_angle - open_angle) / speed
    compliance = 1.0 - body.stiffness
    time_constant = 0.01 + 0.25 * compliance**1.5
    plateau = (60.0 + 180.0 * body.stiffness) * float(rng.uniform(0.9, 1.1))
    squeeze = 0.6 * compliance
    since_contact = np.maximum(t - contact_time, 0.0)
    response = np.where(t >= contact_time, 1.0 - np.exp(-since_contact / time_constant), 0.0)
    haptic = np.clip(plateau * response + rng.normal(0.0, 1.5, FINGER_SAMPLES), 0.0, HAPTIC_FULL_SCALE)
    closing = np.where(t >= contact_time, contact_angle + squeeze * response, open_angle + speed * t)
    proprioceptive = closing + rng.normal(0.0, 0.004, FINGER_SAMPLES)
    return FingerSeries(haptic=haptic, proprioceptive=proprioceptive)


def _audio_behaviour(behaviours: Sequence[str], effects: Mapping[str, BehaviourEffect]) -> str:
    """The behaviour during which audio is recorded: shake (§II-C 3.3), else the grasp, else the first."""
    for kind in ("shake", "lift"):
        for behaviour in behaviours:
            if effects[behaviour].kind == kind:
                return behaviour
    return behaviours[0]


def record_object(
    body: ObjectBody,
    behaviours: Sequence[str],
    effects: Mapping[str, BehaviourEffect],
    rng: np.random.Generator,
    difficulty: Difficulty = EASY,
) -> ObjectRecording:
    """Run the §II-C protocol on one object: a look, then one interaction per applicable behaviour.

    With ``difficulty.lying_probability`` the first look finds the object lying on its side."""
    if not behaviours:
        raise InvalidInputError("behaviours", "an object needs at least one applicable behaviour to be recorded")
    missing = [b for b in behaviours if b not in effects]
    if missing:
        raise InvalidInputError("behaviour_effects", f"no physical effect is defined for {missing}")
    pose = place(rng)
    if difficulty.lying_probability > 0.0 and rng.random() < difficulty.lying_probability:
        pose = Pose(pose.x, pose.y, pose.yaw, tip_heading=float(rng.uniform(-math.pi, math.pi)))
    look = point_cloud(body, pose, rng, difficulty)
    with_audio = _audio_behaviour(behaviours, effects)
    interactions = []
    for behaviour in behaviours:
        effect = effects[behaviour]
        start = place(rng)
        before = point_cloud(body, start, rng, difficulty)
        finger = grasp_finger_series(body, rng) if effect.kind == "lift" else None
        audio = handling_audio(body, rng, shaking=effect.kind == "shake") if behaviour == with_audio else None
        after = point_cloud(body, apply_behaviour(body, start, effect, rng), rng, difficulty)
        interactions.append(Interaction(behaviour=behaviour, before=before, after=after, audio=audio, finger=finger))
    return ObjectRecording(look=look, interactions=tuple(interactions))
