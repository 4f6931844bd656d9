"""The named layout of Table III: entity vector e (91) and effect vector f (66).

No other module hard-codes an index: use the slices here, by name.
Positions in the paper are 1-based (1-3 position ...); these slices are 0-based.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

HISTOGRAM_BINS = 20
MFCC_COEFFICIENTS = 13
FINGER_STATISTICS = ("change", "min", "max", "mean", "variance", "std")


@dataclass(frozen=True)
class FeatureLayout:
    """Ordered named blocks of a feature vector; ``slices[name]`` indexes a block."""

    blocks: tuple[tuple[str, int], ...]

    @cached_property
    def slices(self) -> dict[str, slice]:
        out: dict[str, slice] = {}
        start = 0
        for name, width in self.blocks:
            out[name] = slice(start, start + width)
            start += width
        return out

    @property
    def size(self) -> int:
        return sum(width for _, width in self.blocks)

    def __getitem__(self, name: str) -> slice:
        return self.slices[name]

    @cached_property
    def feature_names(self) -> tuple[str, ...]:
        """One readable name per dimension, e.g. ``position.x``, ``shape_index[3]``, ``haptic.mean``."""
        names: list[str] = []
        for block, width in self.blocks:
            labels = _BLOCK_LABELS.get(block)
            if labels:
                names.extend(f"{block}.{label}" for label in labels)
            else:
                names.extend(f"{block}[{i}]" for i in range(width))
        return tuple(names)


_BLOCK_LABELS: dict[str, tuple[str, ...]] = {
    "position": ("x", "y", "z"),
    "dimensions": ("width", "height", "depth"),
    "haptic": FINGER_STATISTICS,
    "proprioceptive": FINGER_STATISTICS,
}

VISUAL_BLOCKS: tuple[tuple[str, int], ...] = (
    ("position", 3),
    ("dimensions", 3),
    ("normal_zenith", HISTOGRAM_BINS),
    ("normal_azimuth", HISTOGRAM_BINS),
    ("shape_index", HISTOGRAM_BINS),
)

#: Entity feature vector e = (e_v, e_a, e_h, e_p), Table III, 91 dimensions.
ENTITY_LAYOUT = FeatureLayout(
    VISUAL_BLOCKS
    + (
        ("mfcc_range", MFCC_COEFFICIENTS),
        ("haptic", len(FINGER_STATISTICS)),
        ("proprioceptive", len(FINGER_STATISTICS)),
    )
)

#: Effect feature vector f = e'_v - e_v, the visual part only, 66 dimensions.
EFFECT_LAYOUT = FeatureLayout(VISUAL_BLOCKS)

#: The visual part e_v of an entity vector, which is what an effect vector differences.
VISUAL = slice(0, EFFECT_LAYOUT.size)

ENTITY_SIZE = ENTITY_LAYOUT.size
EFFECT_SIZE = EFFECT_LAYOUT.size

assert ENTITY_SIZE == 91 and EFFECT_SIZE == 66
