"""Planar polyline helpers for the generator (NumPy, points as ``[N, 2]`` float64 arrays)."""

from __future__ import annotations

import numpy as np


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``[N]`` along a polyline, starting at 0."""
    seg = np.linalg.norm(np.diff(np.asarray(points, float), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points at (almost) equal arc-length spacing, keeping both end points."""
    s = arc_length(points)
    if s[-1] <= 0:
        return points[:1].copy()
    n = max(int(np.ceil(s[-1] / spacing)), 1)
    t = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], axis=1)


def tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents ``[N, 2]`` (central differences; one-sided at the ends)."""
    g = np.gradient(points, axis=0) if len(points) > 1 else np.array([[1.0, 0.0]])
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)


def offset(points: np.ndarray, d) -> np.ndarray:
    """The polyline shifted by ``d`` (scalar or ``[N]``) metres to its left."""
    t = tangents(points)
    return points + np.asarray(d, float).reshape(-1, 1) * np.stack([-t[:, 1], t[:, 0]], axis=1)


def next_dirs(points: np.ndarray) -> np.ndarray:
    """WOMD ``dir``: unit vector to the next point of the polyline; zero at the last point."""
    d = np.zeros_like(points)
    diff = np.diff(points, axis=0)
    d[:-1] = diff / np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-9)
    return d


def unwrapped_yaw(points: np.ndarray) -> np.ndarray:
    t = tangents(points)
    return np.unwrap(np.arctan2(t[:, 1], t[:, 0]))


def curvature(points: np.ndarray) -> np.ndarray:
    """Signed curvature ``[N]`` (1/m) from the heading change per unit arc length."""
    if len(points) < 3:
        return np.zeros(len(points))
    return np.gradient(unwrapped_yaw(points), arc_length(points))


def bezier_cubic(p0, t0, p1, t1, n: int) -> np.ndarray:
    """Cubic Bezier from ``p0`` leaving along ``t0`` to ``p1`` arriving along ``t1``."""
    p0, t0, p1, t1 = (np.asarray(v, float) for v in (p0, t0, p1, t1))
    u = np.linspace(0.0, 1.0, n)[:, None]
    c0, c1 = p0 + t0, p1 - t1
    return (1 - u) ** 3 * p0 + 3 * (1 - u) ** 2 * u * c0 + 3 * (1 - u) * u**2 * c1 + u**3 * p1


def concat(*pieces: np.ndarray) -> np.ndarray:
    """Join polylines, dropping a piece's first point when it repeats the previous end."""
    out = [pieces[0]]
    for piece in pieces[1:]:
        if len(piece) == 0:
            continue
        if np.linalg.norm(piece[0] - out[-1][-1]) < 1e-6:
            piece = piece[1:]
        out.append(piece)
    return np.concatenate(out, axis=0)


def paths_intersect(xy_a: np.ndarray, valid_a: np.ndarray, xy_b: np.ndarray,
                    valid_b: np.ndarray) -> bool:
    """Whether two logged paths (segments between consecutive valid steps) cross or touch."""
    ok_a, ok_b = valid_a[:-1] & valid_a[1:], valid_b[:-1] & valid_b[1:]
    a0, a1 = xy_a[:-1][ok_a], xy_a[1:][ok_a]
    b0, b1 = xy_b[:-1][ok_b], xy_b[1:][ok_b]
    if len(a0) == 0 or len(b0) == 0:
        return False
    lo_a, hi_a = np.minimum(a0, a1), np.maximum(a0, a1)
    lo_b, hi_b = np.minimum(b0, b1), np.maximum(b0, b1)
    if np.any(hi_a.max(0) < lo_b.min(0)) or np.any(hi_b.max(0) < lo_a.min(0)):
        return False
    # only segments whose box meets the other path's box (+ 1 um margin) can cross
    near_a = ((hi_a >= lo_b.min(0) - 1e-6) & (lo_a <= hi_b.max(0) + 1e-6)).all(1)
    near_b = ((hi_b >= lo_a.min(0) - 1e-6) & (lo_b <= hi_a.max(0) + 1e-6)).all(1)
    a0, a1, b0, b1 = a0[near_a], a1[near_a], b0[near_b], b1[near_b]
    p, r = a0[:, None], (a1 - a0)[:, None]
    q, s = b0[None], (b1 - b0)[None]
    cross = lambda u, v: u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    den = cross(r, s)
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross(qp, s) / den
        u = cross(qp, r) / den
    return bool(((np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)).any())
