"""Ground incidence from local planes (lads/diagnose/data/ground_normals.py)."""

from __future__ import annotations

import numpy as np

from lads.diagnose.data.ground_normals import MIN_POINTS, local_ground_cos

SENSOR_HEIGHT_M = 1.73


def ring_ground(
    n_rings: int = 40, per_ring: int = 2000, slope: float = 0.0, seed: int = 0
) -> np.ndarray:
    """(N, 3) points where 40 rings meet the plane z = slope * x - h, as a spinning sensor
    sees it: dense along each ring, rings metres apart at range, 2 cm range noise."""
    rng = np.random.default_rng(seed)
    elev = np.radians(np.linspace(-24.0, -1.2, n_rings))
    az = rng.uniform(0, 2 * np.pi, (n_rings, per_ring))
    d = np.stack(
        [
            np.cos(elev)[:, None] * np.cos(az),
            np.cos(elev)[:, None] * np.sin(az),
            np.broadcast_to(np.sin(elev)[:, None], az.shape),
        ],
        axis=-1,
    )
    # Ray r d meets z = slope x - h where r (d_z - slope d_x) = -h.
    r = -SENSOR_HEIGHT_M / (d[..., 2] - slope * d[..., 0])
    pts = (d * r[..., None]).reshape(-1, 3)
    pts += rng.normal(0, 0.02, pts.shape) * (pts / np.linalg.norm(pts, axis=1, keepdims=True))
    return pts[np.linalg.norm(pts, axis=1) < 80.0]


def true_cos(pts: np.ndarray, slope: float) -> np.ndarray:
    n = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)
    return np.abs(pts @ n) / np.linalg.norm(pts, axis=1)


def test_far_ground_gets_the_plane_incidence_to_a_fraction_of_a_degree():
    pts = ring_ground()
    cos, ok = local_ground_cos(pts, np.ones(len(pts), bool))
    r = np.linalg.norm(pts, axis=1)
    far = (r > 20.0) & (r < 40.0)
    assert ok[far].all()
    err_deg = np.degrees(np.abs(np.arccos(cos[ok]) - np.arccos(true_cos(pts[ok], 0))))
    assert np.percentile(err_deg, 99) < 0.5
    # Beyond 40 m the rings lie > 10 m apart: a support holding one ring is a line, no plane.
    assert ok[r > 40.0].mean() < 0.5


def test_a_gentle_slope_is_followed_and_a_wall_is_not_called_ground():
    pts = ring_ground(slope=0.08)
    cos, ok = local_ground_cos(pts, np.ones(len(pts), bool))
    assert np.median(np.abs(cos[ok] - true_cos(pts[ok], 0.08))) < 0.01
    steep = ring_ground(slope=0.6)
    _, ok_steep = local_ground_cos(steep, np.ones(len(steep), bool))
    assert not ok_steep.any()


def test_points_off_the_ground_or_without_support_get_no_plane():
    pts = ring_ground()
    ground = np.zeros(len(pts), bool)
    ground[: MIN_POINTS - 1] = True
    cos, ok = local_ground_cos(pts, ground)
    assert not ok.any() and np.isnan(cos).all()
    ground = np.linalg.norm(pts, axis=1) < 30.0
    cos, ok = local_ground_cos(pts, ground)
    assert not ok[~ground].any()
