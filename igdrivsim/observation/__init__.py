"""What the imitator sees: the SDC-frame observation and the partial-observability models.

Pipeline per step (one example; ``jax.vmap`` for batches): the setting's pose models give the
ego's believed pose (Gaussian position noise, one offset per episode) -> the nearest objects and
roadgraph points in that frame as features (:mod:`.features`) -> the setting's hiding models
(fields of view, random masking; :mod:`.models`). ``PRESETS`` holds the paper's six settings
and those registered beyond them (line-of-sight occlusion, :mod:`.occlusion`).
:mod:`.render` draws the settings (paper Fig. 1) and rollout animations.
"""

from igdrivsim.observation.features import (
    OBJECT_FEATURES,
    POSITION_SCALE,
    ROADGRAPH_FEATURES,
    SPEED_SCALE,
    Observation,
    ObservationConfig,
    Selection,
    hide_objects,
    hide_roadgraph,
    object_positions,
    observe_arrays,
    roadgraph_positions,
)
from igdrivsim.observation.models import (
    PAPER_SETTINGS,
    PRESET_SHORT,
    PRESET_TITLES,
    PRESETS,
    CircularFieldOfView,
    ConicFieldOfView,
    FullObservability,
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
    sdc_pose,
    superset_config,
)
from igdrivsim.observation.occlusion import LineOfSightOcclusion, line_of_sight  # registers

__all__ = [
    "OBJECT_FEATURES", "POSITION_SCALE", "ROADGRAPH_FEATURES", "SPEED_SCALE",
    "Observation", "ObservationConfig", "Selection", "hide_objects", "hide_roadgraph",
    "object_positions", "observe_arrays", "roadgraph_positions",
    "PRESET_TITLES", "PRESETS", "CircularFieldOfView", "ConicFieldOfView", "FullObservability",
    "FunctionModel", "GaussianPositionNoise", "ObservationModel", "ObservationSetting",
    "RandomMasking", "apply_setting", "get_setting", "perceive_pose",
    "stack_settings", "register_setting", "PRESET_SHORT",
    "PAPER_SETTINGS",
    "LineOfSightOcclusion", "line_of_sight",
    "observe", "observe_setting_arrays", "observe_with_selection", "sdc_pose",
    "ObservationRecord", "episode_observations", "superset_config",
]
