"""Line-of-sight occlusion (``--obs occlusion``): what lies behind another object's box, seen
from the ego, is hidden.

An object (its centre) or a road point is hidden when the segment from the ego to it crosses
the box of another visible object; the observation carries no sizes, so every occluder is a
``length`` x ``width`` box (a typical car) at its observed pose. An object never occludes
itself, a box containing the ego occludes nothing, and only objects still visible occlude (put
the model first in a composition). Length 0 occludes nothing (its ``neutral()`` form).
"""

from __future__ import annotations

import jax
from flax import struct

from igdrivsim.errors import ConfigError
from igdrivsim.observation.features import Observation, hide_objects, hide_roadgraph
from igdrivsim.observation.models import (
    ObservationModel,
    ObservationSetting,
    concrete,
    register_setting,
)
from igdrivsim.observation.sight import line_of_sight


def occlude(obs: Observation, length: jax.Array | float, width: jax.Array | float) -> Observation:
    """``obs`` without what is out of the ego's line of sight (ONE example); length 0: all kept."""
    keep_objects, keep_roadgraph = line_of_sight(obs, length, width)
    off = length <= 0
    return hide_roadgraph(hide_objects(obs, keep_objects | off), keep_roadgraph | off)


@struct.dataclass
class LineOfSightOcclusion(ObservationModel):
    """Hides objects and road points behind other objects' boxes (``length`` x ``width`` m)."""

    length: float = 4.5
    width: float = 2.0

    def __post_init__(self) -> None:
        if concrete(self.length) and concrete(self.width) and not (
                self.length >= 0 and self.width >= 0):
            raise ConfigError(f"line-of-sight occlusion: length and width must be >= 0 (0: "
                              f"nothing occludes), got {self.length} x {self.width}")

    def apply(self, obs, episode_key, step_key):
        return occlude(obs, self.length, self.width)

    def neutral(self):
        return self.replace(length=0.0, width=0.0)


# its title and short name: igdrivsim.names
register_setting(ObservationSetting("occlusion", (LineOfSightOcclusion(),)))
