"""Calibrated motion (``GeneratorConfig(motion="calibrated")``): the default map and cast with
the driving retuned towards real logs (straighter roads, fewer SDC turns and stops, near-desired
start speeds, varying speeds and lateral offsets); docs/synthetic.md, "Calibrated motion"."""

from __future__ import annotations

import numpy as np

from igdrivsim.data.synthetic.agents import Agent, stop_cap
from igdrivsim.data.synthetic.maps import MapData

MOTIONS = ("default", "calibrated")
ROAD_BEND = 0.15  # road maps: the bends' curvature times this (real streets are straighter)
JUNCTION_SKEW = 0.3  # junctions: the arms' deviation from right angles times this
SPEED_SCALE = (0.5, 1.5)  # per scenario: the map's speed limits times U(lo, hi)
START_SPEED = (0.92, 1.04)  # moving vehicles start at this share of their desired speed
P_SDC_TURN_KEPT = {"left": 0.5, "right": 0.25}  # the SDC's junction turns kept (else straight)
P_LEADER_STOPS = 0.1  # share of braking leaders that still stop (others slow down only)
P_CUT_IN_PULLS_AWAY = 1.0  # share of cut-ins that change lanes faster than the SDC
CROSS_LATER = (3.0, 6.0)  # s: cross traffic reaches the junction this long after the SDC
P_STALLED_KEPT = 0.3  # share of the stalled cars in the SDC's lane kept (others: not there)
P_WALKER_LATE = 0.5  # share of crossing pedestrians that wait at the kerb until t = 5-8 s
SPEED_WAVE = ((0.04, 0.12), (6.0, 16.0))  # desired speed x (1 + a sin(2 pi t / T + phase))
SDC_HEADWAY = (0.9, 1.3)  # s: the SDC's IDM time headway (default 1.6 s)
SDC_ACCEL, SDC_BRAKE = (1.4, 2.2), (0.8, 1.2)  # m/s^2: its IDM a and b (default 1.4, 1.8)
P_SDC_SLOW_START = 0.2  # share of SDCs that start slow (0.2-0.6 of their desired speed)
LANE_BIAS = (-0.12, 0.24)  # m: lateral bias per lane, normal (mean, sd); left positive
DRIVER_BIAS = 0.08  # m: sd of each driver's own bias around the lane's
WANDER = (0.05, 0.25)  # m: amplitude of a slow lateral drift (a long sine), uniform
WAVELENGTH = (150.0, 400.0)  # m: its wavelength, uniform (heading within 0.01 rad of the lane)
MOVING_ROLES = ("sdc", "background", "leader", "follower", "alongside", "cross", "leaving",
                "side", "cut_in", "braking_leader")


def calibrate_map(rng: np.random.Generator, m: MapData) -> None:
    """Scale the speed limits of every route of ``m`` (one factor per scenario)."""
    scale = rng.uniform(*SPEED_SCALE)
    for route in m.routes:
        route.speed_limit *= scale


def calibrate_cast(rng: np.random.Generator, m: MapData, cast: list[Agent]) -> list[Agent]:
    """Retune the drawn ``cast`` (the SDC first) in place, and return it."""
    sdc = cast[0]
    waits = sdc.v0 == 0.0  # the SDC stands in a queue (a road draw the paper's filter drops)
    if m.kind == "intersection" and sdc.route.kind in ("left", "right"):
        if rng.random() > P_SDC_TURN_KEPT[sdc.route.kind]:  # straight on, if it can
            sdc.route = next((r for r in m.routes if r.group == sdc.route.group
                              and r.kind == "straight"), sdc.route)
    biases: dict[int, float] = {}
    for a in cast:
        if a.role == "walker" and not a.static and rng.random() < P_WALKER_LATE:
            a.start_step = max(a.start_step, int(rng.integers(50, 80)))
        if a.static or a.walker or a.role not in MOVING_ROLES or a.is_sdc and waits:
            continue
        start = rng.uniform(*START_SPEED)
        if a.role == "cut_in":  # keeps its own speed relative to the SDC's
            if rng.random() < P_CUT_IN_PULLS_AWAY:
                a.v0 = a.v_des = max(a.v0, sdc.v_des) * rng.uniform(1.1, 1.3)
        elif a.role != "alongside":
            if a.route.group == sdc.route.group and a.s0 > sdc.s0:  # ahead in the SDC's lane:
                a.v_des = max(a.v_des, sdc.v_des * rng.uniform(0.95, 1.1))  # keeps pace
            a.v0 = a.v_des * start
            if a.role == "cross":  # reaches the junction after the SDC has cleared it
                eta = (sdc.route.entry - sdc.s0) / max(sdc.v0, 3.0)
                d = a.v0 * (eta + rng.uniform(*CROSS_LATER))
                a.s0 = float(max(a.route.entry - d, 0.0))
        if a.role == "braking_leader" and rng.random() > P_LEADER_STOPS:
            a.stop_window = None
            a.v_des *= rng.uniform(0.75, 0.95)  # a slower leader: followed, not stopped for
        a.v0 = min(a.v0, stop_cap(a))
        a.speed_wave = (rng.uniform(*SPEED_WAVE[0]), rng.uniform(*SPEED_WAVE[1]),
                        rng.uniform(0, 2 * np.pi))
        a.lateral = (rng.uniform(*WANDER), rng.uniform(*WAVELENGTH), a.lateral[2])
        lane = biases.setdefault(a.route.group, rng.normal(*LANE_BIAS))
        a.offset = float(np.clip(lane + rng.normal(0.0, DRIVER_BIAS), -0.6, 0.4))
    sdc.headway, sdc.min_gap = rng.uniform(*SDC_HEADWAY), 2.0
    sdc.accel, sdc.brake = rng.uniform(*SDC_ACCEL), rng.uniform(*SDC_BRAKE)
    if rng.random() < P_SDC_SLOW_START:
        sdc.v0 = min(sdc.v0, sdc.v_des * rng.uniform(0.2, 0.6))
    cast = [a for a in cast if a.role != "stalled" or waits or rng.random() < P_STALLED_KEPT]
    for a in cast:  # a car alongside the SDC keeps pace with it
        if a.role == "alongside":
            a.v0 = min(sdc.v0 * rng.uniform(0.9, 1.1), stop_cap(a))
    return cast
