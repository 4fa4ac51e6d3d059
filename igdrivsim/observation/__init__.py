"""What the imitator sees: the SDC-frame observation (:mod:`.features`, :mod:`.observe`) under
the partial-observability settings (:mod:`.models`, :mod:`.occlusion`), and their pictures
(:mod:`.render`).
"""

from igdrivsim.observation.features import (
    OBJECT_FEATURES,
    ROADGRAPH_FEATURES,
    Observation,
    ObservationConfig,
    hide_objects,
    hide_roadgraph,
    object_positions,
    roadgraph_positions,
)
from igdrivsim.observation.models import (
    PAPER_SETTINGS,
    PRESET_TITLES,
    PRESETS,
    CircularFieldOfView,
    ConicFieldOfView,
    FunctionModel,
    GaussianPositionNoise,
    ObservationModel,
    ObservationSetting,
    RandomMasking,
    apply_setting,
    get_setting,
    perceive_pose,
    register_setting,
    stack_settings,
)
from igdrivsim.observation.observe import (
    ObservationRecord,
    episode_observations,
    observe,
    observe_setting_arrays,
    observe_with_selection,
    superset_config,
)
from igdrivsim.observation.occlusion import LineOfSightOcclusion, line_of_sight  # registers

__all__ = [
    "OBJECT_FEATURES", "ROADGRAPH_FEATURES", "Observation", "ObservationConfig", "hide_objects",
    "hide_roadgraph", "object_positions", "roadgraph_positions",
    "PRESET_TITLES", "PRESETS", "CircularFieldOfView", "ConicFieldOfView", "FunctionModel",
    "GaussianPositionNoise", "ObservationModel", "ObservationSetting", "RandomMasking",
    "apply_setting", "get_setting", "perceive_pose", "stack_settings", "register_setting",
    "PAPER_SETTINGS", "LineOfSightOcclusion", "line_of_sight",
    "observe", "observe_setting_arrays", "observe_with_selection",
    "ObservationRecord", "episode_observations", "superset_config",
]
