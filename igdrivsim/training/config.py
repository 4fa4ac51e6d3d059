"""Typed run configuration (frozen dataclasses with the paper's defaults) and the profiles.

:class:`RunConfig` = policy widths + data/input settings + observation setting + training
hyper-parameters + the loss's terms. ``PROFILES``: ``smoke`` (seconds, tests), ``laptop`` (the
default), ``quick``, ``gpu`` and ``paper`` (each function's docstring says what it is for). Any
field can be overridden with ``section.field=value`` strings (``--set training.lr=3e-4``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Any

from igdrivsim.core.params import MixWeights, PPOParams
from igdrivsim.data.egos import EGO_MODES
from igdrivsim.data.scenario import Capacities
from igdrivsim.errors import ConfigError
from igdrivsim.names import GPU_SEEDS
from igdrivsim.observation import ObservationConfig, stack_settings, superset_config
from igdrivsim.policy.network import NUM_BINS, POOLED_NETWORK, PolicyConfig
from igdrivsim.simulator import SimParams
from igdrivsim.simulator.agents import AGENTS
from igdrivsim.training.methods import DEFAULT_METHOD, get_method, method_param_defaults


@dataclass(frozen=True)
class DataConfig:
    """Which scenarios feed training and how they are batched."""

    batch_size: int = 256  # scenarios per update (per seed, over all devices and hosts)
    max_scenarios: int = 0  # use at most this many scenarios (0: all)
    max_objects: int = 128  # object slots kept per scenario at load time (SDC + nearest)
    max_roadgraph_points: int = 20_000  # roadgraph points kept at load time (nearest first)
    prefetch: int = 2  # batches prepared ahead by the background thread
    # keep every training scenario's teacher-forced records in memory (cached on disk); False:
    # record each batch inside the update (paper scale: ~10 MB of records per scenario)
    record_teacher: bool = True
    # stream scenarios from disk in per-process shards, a few batches in host memory (paper
    # scale, needs record_teacher=False; igdrivsim.training.stream)
    stream: bool = False
    workers: int = 2  # decode + reset threads of the stream
    buffer: int = 2  # batches the stream prepares ahead (bounds host memory)
    shards: int = 0  # disjoint shards of the data (0: one per process); a multiple of those
    # "sdc": each scenario with its logged SDC as the ego (the paper's); "all": one scenario
    # per vehicle valid over the window that passes the paper's filter as the ego
    egos: str = "sdc"


@dataclass(frozen=True)
class ObsConfig:
    """The imitator's observation: a preset name (``a+b`` composes models), or several
    settings trained together as ``a,b,c``, and the observation capacities."""

    setting: str = "full"
    num_objects: int = 32
    num_roadgraph_points: int = 1500
    # the observable map keeps every k-th point of each polyline (WOMD: 0.5 m apart), so the
    # nearest ``num_roadgraph_points`` reach k times farther (1: the map as stored)
    roadgraph_stride: int = 1


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation and the schedule (paper: Adam, cosine 1e-3 -> 0); the loss's terms are
    :class:`LossConfig`."""

    method: str = DEFAULT_METHOD  # a registered method (igdrivsim/training/methods/): BC
    seeds: int = 3
    seed_offset: int = 0  # seeds are seed_offset .. seed_offset + seeds - 1
    epochs: float = 200.0  # passes over the data (ignored when num_updates > 0)
    num_updates: int = 0
    lr: float = 1e-3
    lr_end: float = 0.0
    grad_clip: float = 1.0  # global gradient-norm clip
    ppo_epochs: int = 4  # gradient passes over each batch (BC and PPO alike)
    ppo_minibatches: int = 4  # minibatches (of scenarios) per pass
    # the same for the methods that drive (0: ppo_epochs / ppo_minibatches), so that the paper
    # profile's BC takes one Adam step per batch as the original did and its BC-RL real epochs
    rollout_epochs: int = 0
    rollout_minibatches: int = 0
    log_every: int = 10
    eval_every: int = 0  # closed-loop validation every N updates (0: never; needs val data)
    val_scenarios: int = 32  # the fixed validation subset of the learning curves
    checkpoint_every: int = 100
    max_checkpoints: int = 2
    # methods with a privileged teacher (dagger, advisor): the run folder of a policy trained
    # with the "full" setting among its settings (the pipeline picks the better of BC / BC-RL)
    teacher: str = ""
    # values of the methods' own hyper-parameters (``--set method.NAME=VALUE``; a method reads
    # its declared ``params``, with their defaults where not set here): ((name, value), ...)
    method_params: tuple = ()
    # who moves the other objects in closed-loop episodes (rollouts, validation, evaluation):
    # "log" (replay, the paper's) or "idm" (reactive vehicles; igdrivsim.simulator.agents)
    sim_agents: str = "log"

    def __post_init__(self):
        object.__setattr__(self, "method_params", tuple(sorted(
            (str(k), v) for k, v in dict(self.method_params).items())))


@dataclass(frozen=True)
class LossConfig(MixWeights, PPOParams):
    """The loss's weights (``w_bc``: every method's imitation term, ``w_rl``: the RL terms of
    BC-RL and ADVISOR) and PPO's coefficients, with the defaults the maze reads
    (:mod:`igdrivsim.core.params`); ``--set loss.w_rl=0.1``."""


@dataclass(frozen=True)
class RunConfig:
    profile: str = "paper"
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    data: DataConfig = field(default_factory=DataConfig)
    observation: ObsConfig = field(default_factory=ObsConfig)
    training: TrainConfig = field(default_factory=TrainConfig)
    loss: LossConfig = field(default_factory=LossConfig)

    @property
    def collects_rollout(self) -> bool:
        """Static flag: every update drives the policy in closed loop (needs reset states)."""
        return get_method(self.training.method).rollout

    @property
    def sgd_passes(self) -> tuple[int, int]:
        """``(epochs, minibatches)`` of this run's method: the gradient passes over each batch
        and the minibatches per pass (one Adam step each)."""
        t = self.training
        if self.collects_rollout:
            return (t.rollout_epochs or t.ppo_epochs, t.rollout_minibatches or t.ppo_minibatches)
        return t.ppo_epochs, t.ppo_minibatches

    def total_updates(self, num_scenarios: int) -> int:
        t = self.training
        if t.num_updates > 0:
            return t.num_updates
        return max(1, math.ceil(t.epochs * num_scenarios / self.data.batch_size))

    def steps_per_update(self) -> tuple[int, int]:
        """``(scenario-steps, gradient steps)`` of one update over every setting and seed."""
        runs = len(self.settings) * self.training.seeds
        epochs, minibatches = self.sgd_passes
        return runs * self.data.batch_size * 80 * epochs, runs * epochs * minibatches

    @property
    def settings(self) -> tuple[str, ...]:
        """The observation settings this run trains (``observation.setting``, a comma list)."""
        return tuple(s.strip() for s in self.observation.setting.split(",") if s.strip())

    @property
    def seeds(self) -> tuple[int, ...]:
        t = self.training
        return tuple(range(t.seed_offset, t.seed_offset + t.seeds))

    @property
    def capacities(self) -> Capacities:
        """What a scenario keeps when it is loaded (object slots, roadgraph points)."""
        return Capacities(max_objects=self.data.max_objects,
                          max_roadgraph_points=self.data.max_roadgraph_points)

    @property
    def obs_config(self) -> ObservationConfig:
        o = self.observation
        return ObservationConfig(o.num_objects, o.num_roadgraph_points)

    @property
    def record_config(self) -> ObservationConfig:
        """What a teacher-forced record holds: a superset of :attr:`obs_config`, from which
        every setting's observation is cut."""
        return superset_config(self.obs_config, self.data.max_objects)

    @property
    def sim_params(self) -> SimParams:
        """Simulator settings of this run (the observable map's resolution; the offroad
        metric's road-edge selection keeps its defaults)."""
        return SimParams(roadgraph_stride=self.observation.roadgraph_stride,
                         agents=self.training.sim_agents)

    def validate(self) -> RunConfig:
        """Check the fields (one-line :class:`ConfigError`) and return the config with what
        the method decides filled in (the auxiliary head)."""
        t, d = self.training, self.data
        method = get_method(t.method)  # a registered method, else a one-line error
        if t.sim_agents not in AGENTS:
            raise ConfigError(f"training.sim_agents must be one of {', '.join(AGENTS)}, "
                              f"got {t.sim_agents!r}")
        if method.teacher and not t.teacher:
            raise ConfigError(f"method {t.method!r} needs a privileged teacher: set "
                              "training.teacher=RUN (a run trained with the full setting)")
        method.with_params(dict(t.method_params))  # the method's own checks
        if t.seeds < 1:
            raise ConfigError(f"training.seeds must be >= 1, got {t.seeds}")
        epochs, minibatches = self.sgd_passes
        if minibatches < 1:
            raise ConfigError(f"training.ppo_minibatches (or rollout_minibatches) must be >= 1, "
                              f"got {minibatches}")
        if d.batch_size < 1 or d.batch_size % minibatches:
            raise ConfigError(f"data.batch_size ({d.batch_size}) must be a positive multiple of "
                              f"the minibatches per pass ({minibatches}: "
                              "training.ppo_minibatches, or rollout_minibatches for a method "
                              "that drives)")
        if d.stream and d.record_teacher:
            raise ConfigError("data.stream needs data.record_teacher=false (the update records "
                              "each streamed batch)")
        if d.egos not in EGO_MODES:
            raise ConfigError(f"data.egos must be one of {', '.join(EGO_MODES)}, got {d.egos!r}")
        if d.workers < 1 or d.buffer < 1 or d.shards < 0:
            raise ConfigError("data.workers and data.buffer must be >= 1, data.shards >= 0")
        if epochs < 1:
            raise ConfigError(f"training.ppo_epochs must be >= 1, got {t.ppo_epochs}")
        for (section, name), (low, high) in RANGES.items():  # tuples: each entry
            value = getattr(getattr(self, section), name)
            for v in value if isinstance(value, tuple) else (value,):
                if (not math.isfinite(v) or (low is not None and v < low)
                        or (high is not None and v > high)):
                    bound = (f">= {low}" if high is None else f"in [{low}, {high}]")
                    raise ConfigError(f"{section}.{name} must be finite and {bound}, got {value}")
        if self.policy.num_bins != NUM_BINS:
            raise ConfigError(f"policy.num_bins must be {NUM_BINS} (the expert's discretised "
                              f"levels), got {self.policy.num_bins}")
        if t.num_updates < 0 or (t.num_updates == 0 and t.epochs <= 0):
            raise ConfigError("set training.num_updates > 0 or training.epochs > 0")
        names = list(self.settings)
        if not names or len(set(names)) != len(names):
            raise ConfigError("observation.setting must name distinct settings, got "
                              f"{self.observation.setting!r}")
        if len(names) > 1 and stack_settings(names) is None:
            raise ConfigError(f"observation.setting={self.observation.setting!r}: these settings "
                              "cannot share one program (a model that is not a pytree or has "
                              "no neutral() form, or two orders of the same models; "
                              "docs/EXTENDING.md); train a custom setting on its own")
        value_head = self.policy.value_head
        if value_head is False and method.rollout:
            raise ConfigError(f"method {t.method!r} learns values: policy.value_head must not "
                              "be false")
        decided = {"aux_head": method.aux_head,
                   "value_head": method.rollout if value_head is None else value_head}
        return dataclasses.replace(self, policy=dataclasses.replace(self.policy, **decided))


SECTIONS = {"policy": PolicyConfig, "data": DataConfig, "observation": ObsConfig,
            "training": TrainConfig, "loss": LossConfig}

# (section, field) -> (lowest, highest) allowed; None: unbounded on that side. Sizes and periods
# are at least 1; rates are finite. The fields not named here are checked in ``validate``.
RANGES: dict[tuple[str, str], tuple[float | None, float | None]] = {
    **{("policy", f): (1, None) for f in ("object_hidden", "point_hidden", "roadgraph_hidden",
                                          "trunk_hidden", "gru_hidden", "actor_hidden",
                                          "value_hidden")},
    ("policy", "speed_history"): (0, None), ("policy", "yaw_history"): (0, None),
    ("policy", "speed_input_scale"): (0, None),
    ("data", "max_scenarios"): (0, None), ("data", "max_objects"): (1, None),
    ("data", "max_roadgraph_points"): (1, None), ("data", "prefetch"): (0, None),
    ("observation", "num_objects"): (1, None), ("observation", "num_roadgraph_points"): (1, None),
    ("observation", "roadgraph_stride"): (1, None),
    ("training", "seed_offset"): (0, None), ("training", "epochs"): (0, None),
    ("training", "lr"): (0, None), ("training", "lr_end"): (0, None),
    ("training", "grad_clip"): (0, None), ("loss", "w_bc"): (0, None),
    ("loss", "w_rl"): (0, None), ("loss", "gamma"): (0, 1),
    ("loss", "gae_lambda"): (0, 1), ("loss", "clip_eps"): (0, None),
    ("loss", "ent_coef"): (0, None), ("loss", "vf_coef"): (0, None),
    ("training", "ppo_minibatches"): (1, None), ("training", "log_every"): (1, None),
    ("training", "rollout_epochs"): (0, None), ("training", "rollout_minibatches"): (0, None),
    ("training", "eval_every"): (0, None), ("training", "val_scenarios"): (0, None),
    ("training", "checkpoint_every"): (1, None), ("training", "max_checkpoints"): (1, None),
}


def smoke() -> RunConfig:
    """Seconds on a CPU: tiny network, tiny capacities, a handful of updates."""
    return RunConfig(
        profile="smoke",
        policy=PolicyConfig(**POOLED_NETWORK, object_hidden=(16,), point_hidden=(16,),
                            roadgraph_hidden=(16,), trunk_hidden=(16,), gru_hidden=16,
                            actor_hidden=(16,), value_hidden=(16,)),
        data=DataConfig(batch_size=4, max_scenarios=16, max_objects=8, max_roadgraph_points=256),
        observation=ObsConfig(num_objects=4, num_roadgraph_points=32),
        training=TrainConfig(seeds=2, num_updates=4, ppo_epochs=2, ppo_minibatches=2,
                             log_every=1, eval_every=4, val_scenarios=4, checkpoint_every=2),
    )


# The laptop profile's budget: where Full BC meets the competence targets it can at this
# compute (paper/findings.tex, "On the calibrated scenes"; docs/bench/competence_sweep_h200.md).
COMPETENT_UPDATES = 1000
QUICK_UPDATES = 300


def laptop() -> RunConfig:
    """The default: ``COMPETENT_UPDATES`` updates, about 3 hours for 6 settings x 2 methods x 3
    seeds on a 2-core CPU, with the choices of the sweep in paper/findings.tex (the map thinned
    to every 8th point, dx offsets from constant velocity, speed and yaw-rate histories)."""
    return RunConfig(
        profile="laptop",
        policy=PolicyConfig(**POOLED_NETWORK, object_hidden=(64, 64), point_hidden=(32,),
                            roadgraph_hidden=(64,), trunk_hidden=(128,), gru_hidden=128,
                            actor_hidden=(128,), value_hidden=(64,), relative_dx=True,
                            speed_input_scale=10.0, speed_history=8,
                            yaw_history=5, object_ego_speed=True),
        data=DataConfig(batch_size=16, max_objects=32, max_roadgraph_points=10_240),
        observation=ObsConfig(num_objects=16, num_roadgraph_points=64, roadgraph_stride=8),
        training=TrainConfig(seeds=3, num_updates=COMPETENT_UPDATES, lr=3e-3, ppo_epochs=2,
                             ppo_minibatches=4, log_every=10, eval_every=250, val_scenarios=32,
                             checkpoint_every=50),
    )


def quick() -> RunConfig:
    """The laptop network at ``QUICK_UPDATES`` updates: a first look in about 50 minutes on 2
    cores; its Full BC misses the competence targets."""
    base = laptop()
    return dataclasses.replace(base, profile="quick", training=dataclasses.replace(
        base.training, num_updates=QUICK_UPDATES, eval_every=50, checkpoint_every=50))


def paper() -> RunConfig:
    """The original code's network (``PolicyConfig``'s defaults) and sample budget: 256
    scenarios per update, 200 epochs, 3 seeds, gradient norm clipped at 0.5; BC one Adam step
    per batch as the original, BC-RL 4 PPO epochs of 4 minibatches (so that the ratio moves)."""
    return RunConfig(profile="paper", policy=PolicyConfig(remat=True),
                     data=DataConfig(record_teacher=False, stream=True),
                     training=TrainConfig(grad_clip=0.5, ppo_epochs=1, ppo_minibatches=1,
                                          rollout_epochs=4, rollout_minibatches=4))


def gpu() -> RunConfig:
    """The laptop run with ``GPU_SEEDS`` seeds for power and twice the validation subset: minutes
    on one GPU, about four times the laptop run on a 2-core CPU."""
    base = laptop()
    return dataclasses.replace(base, profile="gpu", training=dataclasses.replace(
        base.training, seeds=GPU_SEEDS, val_scenarios=64))


PROFILES = {"smoke": smoke, "laptop": laptop, "quick": quick, "gpu": gpu, "paper": paper}


def get_profile(name: str) -> RunConfig:
    if name not in PROFILES:
        raise ConfigError(f"unknown profile {name!r}; choose from {', '.join(PROFILES)}")
    return PROFILES[name]()


def _parse_value(text: str, current: Any, where: str) -> Any:
    """Parse ``text`` to the type of the current value (JSON syntax for tuples and lists)."""
    try:
        if current is None:  # a field the method decides unless set: a bool
            current = False
        if isinstance(current, bool):
            low = text.strip().lower()
            if low not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(text)
            return low in ("true", "1", "yes")
        if isinstance(current, (int, float)):
            return type(current)(text)
        if isinstance(current, tuple):
            value = json.loads(text if text.strip().startswith("[") else f"[{text}]")
            return tuple(type(current[0])(v) if current else v for v in value)
        return text
    except (ValueError, TypeError) as err:
        raise ConfigError(f"bad value {text!r} for {where} (expected {type(current).__name__})"
                          ) from err


def with_overrides(config: RunConfig, overrides: list[str]) -> RunConfig:
    """Apply ``section.field=value`` overrides (e.g. ``training.lr=3e-4``)."""
    for item in overrides:
        key, sep, text = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot:
            raise ConfigError(f"override {item!r} must look like section.field=value")
        if section == "method":  # a hyper-parameter a registered method declares
            config = _with_method_param(config, name, text, item)
            continue
        if section not in SECTIONS:
            raise ConfigError(f"unknown config section {section!r} in {item!r}; "
                              f"choose from {', '.join(SECTIONS)} (or method.NAME)")
        sub = getattr(config, section)
        names = {f.name for f in dataclasses.fields(sub)}
        if section == "training" and name in {f.name for f in dataclasses.fields(LossConfig)}:
            raise ConfigError(f"{key!r} is in the loss section: --set loss.{name}={text}")
        if name not in names:
            raise ConfigError(f"unknown field {key!r}; {section} has {', '.join(sorted(names))}")
        value = _parse_value(text, getattr(sub, name), key)
        config = dataclasses.replace(config, **{section: dataclasses.replace(sub, **{name: value})})
    return config


def _with_method_param(config: RunConfig, name: str, text: str, item: str) -> RunConfig:
    declared = method_param_defaults()
    if name not in declared:
        raise ConfigError(f"unknown method parameter {name!r} in {item!r}; the registered "
                          f"methods declare {', '.join(sorted(declared)) or 'none'}")
    value = _parse_value(text, declared[name], item)
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{item!r}: the value must be finite")
    params = dict(config.training.method_params) | {name: value}
    return dataclasses.replace(config, training=dataclasses.replace(
        config.training, method_params=tuple(params.items())))


def to_dict(config: RunConfig) -> dict:
    return dataclasses.asdict(config)


# training fields that became a method's own params: old name -> (param, its default)
MOVED_TO_METHOD_PARAMS = {"advisor_alpha": ("alpha", 1.0),
                          "aggregate_batches": ("aggregate_batches", 4)}


def upgrade_config(d: dict) -> dict:
    """An older ``config.json`` in today's layout (the one place that knows older layouts): the
    loss terms once under ``training`` go to ``loss``; ``advisor_alpha`` and ``aggregate_batches``
    become method params (kept when not their default); a policy without ``object_encoder`` was
    the pooled network with a value head."""
    d = {k: dict(v) if isinstance(v, dict) else v for k, v in d.items()}
    training = d.get("training", {})
    loss_fields = {f.name for f in dataclasses.fields(LossConfig)}
    if moved := {k: training.pop(k) for k in list(training) if k in loss_fields}:
        d["loss"] = {**moved, **d.get("loss", {})}
    if moved := {old: training.pop(old) for old in MOVED_TO_METHOD_PARAMS if old in training}:
        training["method_params"] = [*training.get("method_params", []), *[
            (MOVED_TO_METHOD_PARAMS[old][0], v) for old, v in moved.items()
            if v != MOVED_TO_METHOD_PARAMS[old][1]]]
    if d.get("policy") and "object_encoder" not in d["policy"]:
        d["policy"] = {**POOLED_NETWORK, "value_head": True, **d["policy"]}
    return d


def from_dict(d: dict) -> RunConfig:
    """Inverse of :func:`to_dict` (lists become tuples again; an older layout is upgraded
    first, :func:`upgrade_config`); unknown keys are errors."""
    d = upgrade_config(d)
    kwargs: dict[str, Any] = {"profile": d.get("profile", "custom")}
    for section, cls in SECTIONS.items():
        values = d.get(section, {})
        if unknown := set(values) - {f.name for f in dataclasses.fields(cls)}:
            raise ConfigError(f"config.json: unknown key {section}.{sorted(unknown)[0]}")
        kwargs[section] = cls(**{k: tuple(v) if isinstance(v, list) else v
                                 for k, v in values.items()})
    return RunConfig(**kwargs)
