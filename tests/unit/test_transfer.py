"""Sensor transfer (lads/transfer): surfels, the target's ray cast, moving things, baselines
and metrics, on scenes whose answer is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lads.errors import InputDataError
from lads.sensors.profile import load_profile
from lads.synth.frames import detection_limit, synth_frames
from lads.transfer.baselines import nearest_rings, ring_drop
from lads.transfer.fov import covered_rings
from lads.transfer.metrics import GridScan, compare_scans, grid_column
from lads.transfer.scan import WindowScan, transfer_scan
from lads.transfer.surfels import scan_surfels

HDL64, HDL32 = load_profile("hdl64e"), load_profile("hdl32e")


def _always(albedo, cos, range_m):
    return np.ones(np.shape(range_m), dtype=bool)


def wall_scan(profile, x_m: float, half_width_deg: float = 30.0, label: int = 50):
    """The source's own beams on the plane x = x_m within +-half_width_deg of azimuth, exact
    (no range noise): (xyz, intensity, labels, ring)."""
    el = np.radians(np.asarray(profile.elevation_deg))
    width = profile.range_image_width
    az = (np.arange(width) + 0.5) * 2 * math.pi / width
    az = np.where(az > math.pi, az - 2 * math.pi, az)
    az = az[np.abs(az) < math.radians(half_width_deg)]
    e, a = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    t = x_m / d[..., 0]
    xyz = (d * t[..., None]).reshape(-1, 3)
    ring = np.repeat(np.arange(profile.channels), len(az))
    n = len(xyz)
    intensity = profile.intensity.from_reflectivity(np.full(n, 0.3))
    return xyz.astype(np.float32), intensity, np.full(n, label, np.uint32), ring


def test_a_wall_is_scanned_at_the_target_elevations_and_its_exact_range():
    xyz, inten, labels, ring = wall_scan(HDL64, 10.0)
    scan = WindowScan(xyz, inten, labels, ring, np.eye(4))
    out = transfer_scan(
        [scan],
        0,
        HDL64,
        HDL32,
        np.random.default_rng(0),
        label_set="semantickitti",
        detector=_always,
    )
    el = np.degrees(np.arctan2(out.xyz[:, 2], np.hypot(out.xyz[:, 0], out.xyz[:, 1])))
    want = np.asarray(HDL32.elevation_deg)[out.ring]
    assert np.abs(el - want).max() < 1e-3
    assert np.abs(out.xyz[:, 0] - 10.0).max() < 2e-3  # the plane, to float32 precision
    assert set(np.unique(out.labels)) == {50}
    # Every target ring the source's field of view covers sees the wall across its width.
    covered = covered_rings(HDL64.elevation_deg, HDL32.elevation_deg)
    per_ring = np.bincount(out.ring, minlength=32)
    columns = 2 * 30.0 / (360.0 / HDL32.range_image_width)
    assert (per_ring[covered] >= 0.9 * columns).all()
    el32 = np.asarray(HDL32.elevation_deg)
    beyond = (el32 > max(HDL64.elevation_deg) + 1.0) | (el32 < min(HDL64.elevation_deg) - 1.0)
    assert beyond.sum() >= 6 and (per_ring[beyond] == 0).all()  # nothing the source saw
    # Provenance: each point names a source return on the wall.
    src = xyz[out.source_point]
    assert np.abs(src[:, 0] - 10.0).max() < 1e-3


def ground_scan(profile, height_m: float = 1.8, max_range_m: float = 80.0):
    """The source's own downward beams on flat ground z = -height_m within max_range_m, all
    round, exact: (xyz, intensity, labels, ring)."""
    el = np.radians(np.asarray(profile.elevation_deg))
    width = profile.range_image_width
    az = (np.arange(width) + 0.5) * 2 * math.pi / width
    e, a = np.meshgrid(el, az, indexing="ij")
    ring = np.broadcast_to(np.arange(profile.channels)[:, None], e.shape)
    down = np.sin(e) < 0
    t = np.where(down, height_m / -np.where(down, np.sin(e), -1.0), np.inf)
    keep = t <= max_range_m
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    xyz = (d * np.where(keep, t, 0.0)[..., None])[keep]
    n = len(xyz)
    intensity = profile.intensity.from_reflectivity(np.full(n, 0.2))
    return xyz.astype(np.float32), intensity, np.full(n, 40, np.uint32), ring[keep]


def test_far_ground_between_sparse_rings_has_its_normal_and_no_gaps():
    # An HDL-32E meets flat ground metres apart beyond 20 m: each ring's return still lies on
    # the line of its column's neighbours, so its surfel lies flat and the ground shows on
    # the HDL-64E's rings in between.
    xyz, inten, labels, ring = ground_scan(HDL32)
    s = scan_surfels(xyz, HDL32.intensity.to_reflectivity(inten), HDL32, labels=labels, ring=ring)
    far = np.linalg.norm(s.centre, axis=1) > 20.0
    assert far.sum() > 1000
    assert np.abs(s.normal[far, 2]).min() > 0.999  # flat, also on the last ring of the ground
    out = transfer_scan(
        [WindowScan(xyz, inten, labels, ring, np.eye(4))],
        0,
        HDL32,
        HDL64,
        np.random.default_rng(0),
        label_set="semantickitti",
        detector=_always,
    )
    el64 = np.radians(np.asarray(HDL64.elevation_deg))
    reach = 1.8 / -np.sin(el64)
    inside = (el64 < 0) & (reach < 0.9 * 80.0) & (reach > 3.0)
    per_ring = np.bincount(out.ring, minlength=HDL64.channels)
    assert inside.sum() > 30
    assert (per_ring[inside] >= 0.95 * HDL64.range_image_width).all()
    assert np.abs(out.xyz[:, 2] + 1.8).max() < 1e-2  # on the ground


def test_a_return_in_front_of_far_ground_does_not_continue_its_line():
    # A post at 20 m stands on the ground's row: its return is no part of the ground's line,
    # so it keeps a normal facing the sensor, not the ground's.
    xyz, inten, labels, ring = ground_scan(HDL32)
    column = np.round(np.arctan2(xyz[:, 1], xyz[:, 0]) / (2 * math.pi / HDL32.range_image_width))
    rng_m = np.linalg.norm(xyz, axis=1)
    on_ring = np.flatnonzero((column == 3) & (rng_m > 25.0) & (rng_m < 45.0))
    post = on_ring[np.argmin(rng_m[on_ring])]
    xyz[post] *= 20.0 / rng_m[post]
    s = scan_surfels(xyz, HDL32.intensity.to_reflectivity(inten), HDL32, labels=labels, ring=ring)
    row = np.flatnonzero(s.point == post)[0]
    assert abs(s.normal[row, 2]) < 0.5


def test_a_moving_instance_comes_from_the_centre_scan_only():
    wall = wall_scan(HDL64, 12.0)
    car_now = wall_scan(HDL64, 8.0, half_width_deg=5.0, label=(7 << 16) | 10)
    car_before = wall_scan(HDL64, 6.0, half_width_deg=5.0, label=(7 << 16) | 10)

    def scan(*parts):
        xyz, inten, labels, ring = (np.concatenate(p) for p in zip(*parts, strict=True))
        return WindowScan(xyz, inten, labels, ring, np.eye(4))

    window = [scan(wall, car_before), scan(wall, car_now)]
    out = transfer_scan(
        window,
        1,
        HDL64,
        HDL32,
        np.random.default_rng(0),
        label_set="semantickitti",
        detector=_always,
    )
    car = (out.labels >> 16) == 7
    assert car.any()
    assert np.abs(out.xyz[car, 0] - 8.0).max() < 0.01  # where it is now, not 2 m nearer
    assert (out.source_frame[car] == 1).all()
    # Within the jitter of a parked car's centroid (0.2 m < MOVING_INSTANCE_M) the neighbour
    # lends it: its nearer surfels then win the beams.
    parked = wall_scan(HDL64, 7.8, half_width_deg=5.0, label=(7 << 16) | 10)
    out2 = transfer_scan(
        [scan(wall, parked), scan(wall, car_now)],
        1,
        HDL64,
        HDL32,
        np.random.default_rng(0),
        label_set="semantickitti",
        detector=_always,
    )
    assert 0 in set(out2.source_frame[(out2.labels >> 16) == 7].tolist())


def test_zero_range_points_give_no_surfel_and_provenance_names_file_rows():
    xyz, inten, labels, ring = wall_scan(HDL64, 10.0, half_width_deg=3.0)
    xyz = np.concatenate([np.zeros((5, 3), np.float32), xyz])
    refl = HDL64.intensity.to_reflectivity(np.concatenate([np.zeros(5), inten]))
    s = scan_surfels(xyz, refl, HDL64, ring=np.concatenate([np.zeros(5, int), ring]))
    assert len(s) == len(xyz) - 5 and s.point.min() == 5
    assert np.allclose(np.linalg.norm(s.normal, axis=1), 1.0)
    assert (s.normal[:, 0] < -0.99).all()  # the wall faces the sensor


def test_a_window_without_its_centre_or_with_a_bad_pose_is_refused():
    xyz, inten, labels, ring = wall_scan(HDL64, 10.0, half_width_deg=3.0)
    good = WindowScan(xyz, inten, labels, ring, np.eye(4))
    with pytest.raises(InputDataError, match="centre 2"):
        transfer_scan([good], 2, HDL64, HDL32, np.random.default_rng(0))
    bad = WindowScan(xyz, inten, labels, ring, np.full((4, 4), np.nan))
    with pytest.raises(InputDataError, match="pose of window scan 1"):
        transfer_scan([good, bad], 0, HDL64, HDL32, np.random.default_rng(0))


def test_ring_dropping_keeps_each_source_ring_once_and_the_target_point_count():
    chosen = nearest_rings(HDL64.elevation_deg, HDL32.elevation_deg)
    inside = chosen[chosen >= 0]
    assert len(set(inside.tolist())) == len(inside)
    xyz, inten, labels, ring = wall_scan(HDL64, 10.0)
    base = ring_drop(xyz, inten, labels, ring, HDL64, HDL32)
    per_ring = np.bincount(base.ring, minlength=32)
    assert (per_ring[chosen < 0] == 0).all()
    columns = 2 * 30.0 / (360.0 / HDL32.range_image_width)
    assert np.abs(per_ring[chosen >= 0] - columns).max() <= 2  # every second point kept


def test_metrics_of_a_scan_against_itself_are_perfect():
    frame = next(synth_frames(HDL32, frames=1, seed=2))
    cols = grid_column(frame.xyz, HDL32.range_image_width, 0.0)
    g = GridScan(frame.xyz, frame.ring, cols, frame.labels, frame.intensity)
    m = compare_scans(g, g, 32, HDL32.range_image_width, np.ones(32, bool))
    assert m["ring_count_error_max"] == 0.0 and m["range_error_median_m"] == 0.0
    assert m["label_accuracy"] == 1.0 and m["chamfer_m"] == 0.0 and m["intensity_mae"] == 0.0


def test_on_a_synthetic_street_the_transfer_matches_the_direct_render_better_than_ring_dropping():
    """64 -> 32 over a 4-scan window of a street lads.synth renders with both sensors."""
    seed, centre = 21, 2
    src = list(synth_frames(HDL64, frames=4, seed=seed))
    ref = list(synth_frames(HDL32, frames=4, seed=seed))[centre]
    offset = float(np.random.default_rng([seed, 5, centre]).uniform(-0.5, 0.5)) * (
        2 * math.pi / HDL32.range_image_width
    )  # the synthetic target's firing phase
    limit = detection_limit(HDL32)
    window = [WindowScan(f.xyz, f.intensity, f.labels, f.ring, f.pose) for f in src]
    out = transfer_scan(
        window,
        centre,
        HDL64,
        HDL32,
        np.random.default_rng(1),
        label_set="semantickitti",
        azimuth_offset_rad=offset,
        detector=lambda a, c, r: a / (r * r) >= limit,
    )
    again = transfer_scan(
        window,
        centre,
        HDL64,
        HDL32,
        np.random.default_rng(1),
        label_set="semantickitti",
        azimuth_offset_rad=offset,
        detector=lambda a, c, r: a / (r * r) >= limit,
    )
    assert np.array_equal(out.xyz, again.xyz) and np.array_equal(out.labels, again.labels)
    width = HDL32.range_image_width
    reference = GridScan(
        ref.xyz, ref.ring, grid_column(ref.xyz, width, offset), ref.labels, ref.intensity
    )
    covered = covered_rings(HDL64.elevation_deg, HDL32.elevation_deg)
    mine = compare_scans(
        GridScan(out.xyz, out.ring, out.column, out.labels, out.intensity),
        reference,
        32,
        width,
        covered,
    )
    c = src[centre]
    base = ring_drop(c.xyz, c.intensity, c.labels, c.ring, HDL64, HDL32, azimuth_offset_rad=offset)
    theirs = compare_scans(
        GridScan(base.xyz, base.ring, base.column, base.labels, base.intensity),
        reference,
        32,
        width,
        covered,
    )
    assert mine["range_error_median_m"] < 0.03 < theirs["range_error_median_m"]
    assert mine["chamfer_m"] < theirs["chamfer_m"]
    assert mine["label_accuracy"] > 0.95 and mine["ring_count_error_mean"] < 0.05


def _pose_line(m: np.ndarray) -> str:
    return " ".join(f"{v:.9e}" for v in m[:3, :].reshape(-1)) + "\n"


def test_kitti_poses_are_turned_into_velodyne_poses(synthetic_tree):
    from lads.errors import CorruptItemError
    from lads.readers import get_reader

    root = synthetic_tree("semantickitti", sequences={"00": 3}, labelled=("00",))
    seq = root / "sequences" / "00"
    tr = np.eye(4)
    tr[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # Velodyne -> camera axes, as KITTI's
    tr[:3, 3] = [0.3, -0.1, -0.2]
    calib = (seq / "calib.txt").read_text().splitlines()
    calib = [line for line in calib if not line.startswith("Tr:")] + ["Tr: " + _pose_line(tr)]
    (seq / "calib.txt").write_text("\n".join(calib))
    cams = []
    for i in range(3):
        p = np.eye(4)
        p[2, 3] = 2.0 * i  # the camera drives forward along its z
        cams.append(p)
    (seq / "poses.txt").write_text("".join(_pose_line(p) for p in cams))
    reader = get_reader("semantickitti", root)
    poses = reader.sensor_poses(reader.items())
    last = poses["sequences/00/velodyne/000002.bin"]
    assert np.allclose(last[:3, :3], np.eye(3)) and np.allclose(last[:3, 3], [4.0, 0.0, 0.0])
    (seq / "poses.txt").write_text(_pose_line(cams[0]))
    with pytest.raises(CorruptItemError, match="poses.txt: 1 poses, none for scan 1"):
        reader.sensor_poses(reader.items())
    (seq / "poses.txt").unlink()
    with pytest.raises(CorruptItemError, match="poses.txt: cannot read"):
        reader.sensor_poses(reader.items())
    (seq / "poses.txt").write_text("".join(_pose_line(p) for p in cams))
    (seq / "calib.txt").write_text("P0: " + " ".join(["0"] * 12) + "\n")
    with pytest.raises(CorruptItemError, match="no 'Tr:' line"):
        reader.sensor_poses(reader.items())
    # A placeholder Tr or a mirrored pose is no rigid transform: named, not a singular matrix.
    (seq / "calib.txt").write_text("Tr: " + " ".join(["1"] * 12) + "\n")
    with pytest.raises(CorruptItemError, match="calib.txt: the calibration, line 'Tr': not a rig"):
        reader.sensor_poses(reader.items())
    (seq / "calib.txt").write_text("Tr: " + _pose_line(tr))
    mirrored = cams[1].copy()
    mirrored[0, 0] = -1.0
    (seq / "poses.txt").write_text("".join(_pose_line(p) for p in (cams[0], mirrored, cams[2])))
    with pytest.raises(CorruptItemError, match=r"poses, line 2: not a rigid .* det R = -1"):
        reader.sensor_poses(reader.items())


def test_nuscenes_kitti_poses_are_read_line_by_keyframe(synthetic_tree):
    from lads.errors import CorruptItemError
    from lads.readers import get_reader

    root = synthetic_tree("nuscenes-kitti", scenes={"train/0001": 2})
    lines = []
    for i in range(2):
        p = np.eye(4)
        p[:3, 3] = [10.0 * i, 1.0, 1.83]
        lines.append(_pose_line(p))
    (root / "train/0001/poses.txt").write_text("".join(lines))
    reader = get_reader("nuscenes-kitti", root)
    poses = reader.sensor_poses(reader.items())
    assert np.allclose(poses["train/0001/velodyne/000001.bin"][:3, 3], [10.0, 1.0, 1.83])
    (root / "train/0001/poses.txt").write_text("1 2 3\n")
    with pytest.raises(CorruptItemError, match="line 1 has 3 numbers"):
        reader.sensor_poses(reader.items())


def test_a_surface_the_source_detected_is_as_bright_as_its_detection_implies():
    """A wall whose returns store intensity 0 (below the encoding's step) was still detected:
    its surfels keep the least albedo the source's detection limit implies, and a target as
    sensitive sees the wall; without that floor the stored 0 hides it."""
    xyz, _, labels, ring = wall_scan(HDL64, 20.0)
    dark = HDL64.intensity.from_reflectivity(np.zeros(len(xyz)))
    s = scan_surfels(xyz, HDL64.intensity.to_reflectivity(dark), HDL64, labels=labels, ring=ring)
    assert np.all(s.albedo == 0.0)
    r = np.linalg.norm(s.centre, axis=1)
    want = HDL64.detection.power * r**3 / 20.0  # P_lim R^2 / cos, cos = x / R on the wall
    assert np.allclose(s.least_albedo, want, rtol=0.01)
    scan = WindowScan(xyz, dark, labels, ring, np.eye(4))
    half_limit = 0.5 * HDL64.detection.power

    def as_sensitive(albedo, cos, range_m):
        return albedo * cos / (range_m * range_m) >= half_limit

    def run(floor):
        return transfer_scan(
            [scan], 0, HDL64, HDL32, np.random.default_rng(0),
            label_set="semantickitti", detector=as_sensitive, floor=floor,
        )  # fmt: skip

    seen = run(None)
    assert len(seen.ring) > 0.9 * len(run(lambda cos, r: np.full(np.shape(r), np.inf)).ring)
    assert len(run(lambda cos, r: np.zeros(np.shape(r))).ring) == 0
    assert np.all(seen.intensity == 0.0)  # the floor decides detection, not the intensity
