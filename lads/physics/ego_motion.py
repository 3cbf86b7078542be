"""The vehicle's motion during one sweep: a velocity and an angular velocity in the sensor
frame, given, or estimated from the poses of the neighbouring scans (docs/augment.md §3).

The motion-distortion corruption reads it (`lads.physics.sensor_faults.motion_distortion`).
Over one sweep (0.05-0.1 s) the motion is taken as constant: the central difference of the
poses of the scans before and after the frame gives it, as a LiDAR-odometry de-skewing step
would assume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import InputDataError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class EgoMotion:
    """Constant motion of the sensor over one sweep, in the sensor frame of mid-sweep.

    Attributes:
        velocity_m_s: (vx, vy, vz) of the sensor, m/s.
        angular_velocity_deg_s: (wx, wy, wz) rotation rate, deg/s (wz > 0: turning left
            when z points up).
    """

    velocity_m_s: tuple[float, float, float]
    angular_velocity_deg_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def speed_m_s(self) -> float:
        """|v|, m/s."""
        return float(math.hypot(*self.velocity_m_s))

    @property
    def yaw_rate_deg_s(self) -> float:
        """Rotation rate about the sensor's z axis, deg/s."""
        return float(self.angular_velocity_deg_s[2])

    def params(self) -> dict[str, list[float]]:
        """The stage parameters that give this motion (`lads.augment.corrupt(...,
        corruption="motion_distortion", **motion.params())`)."""
        return {
            "velocity_m_s": [float(v) for v in self.velocity_m_s],
            "angular_velocity_deg_s": [float(w) for w in self.angular_velocity_deg_s],
        }


def straight(speed_m_s: float, yaw_rate_deg_s: float, forward_azimuth_deg: float) -> EgoMotion:
    """Driving at `speed_m_s` along the sensor's forward azimuth, turning at `yaw_rate_deg_s`
    about z (the severity presets' motion)."""
    forward = math.radians(forward_azimuth_deg)
    return EgoMotion(
        (speed_m_s * math.cos(forward), speed_m_s * math.sin(forward), 0.0),
        (0.0, 0.0, float(yaw_rate_deg_s)),
    )


def from_poses(times_s: npt.ArrayLike, poses: npt.ArrayLike, centre: int, where: str) -> EgoMotion:
    """The motion at scan `centre` from the poses of its neighbours (central difference;
    one-sided at the ends of a sequence).

    Args:
        times_s: (K,) float64 s, the scans' times, increasing; K >= 2.
        poses: (K, 4, 4) float64 sensor -> world poses of the same scans.
        centre: index of the frame's own scan in both.
        where: what the poses came from, for messages (a file or a scene).

    Returns:
        EgoMotion in the sensor frame of scan `centre`.

    Raises:
        InputDataError: fewer than two scans, or times that do not increase.
    """
    t = np.asarray(times_s, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    if t.size < 2 or p.shape != (t.size, 4, 4) or not 0 <= centre < t.size:
        raise InputDataError(
            f"{where}: the poses of the scans before or after the frame are missing; motion "
            "from poses needs the pose and time of at least one neighbouring scan."
        )
    before, after = max(centre - 1, 0), min(centre + 1, t.size - 1)
    dt = float(t[after] - t[before])
    if not dt > 0.0 or not math.isfinite(dt):
        raise InputDataError(
            f"{where}: scan times {t[before]!r} and {t[after]!r} do not increase; expected "
            "one time per scan, in scan order (e.g. KITTI's times.txt)."
        )
    # scipy.spatial costs ~70 ms to import: only builds that read poses pay it.
    from scipy.spatial.transform import Rotation

    inverse = np.linalg.inv(p[centre])
    rel_before, rel_after = inverse @ p[before], inverse @ p[after]
    velocity = (rel_after[:3, 3] - rel_before[:3, 3]) / dt
    turn = Rotation.from_matrix(rel_after[:3, :3]).as_rotvec()
    turn -= Rotation.from_matrix(rel_before[:3, :3]).as_rotvec()
    omega = np.degrees(turn) / dt
    return EgoMotion(
        (float(velocity[0]), float(velocity[1]), float(velocity[2])),
        (float(omega[0]), float(omega[1]), float(omega[2])),
    )


def rotate_about(xyz: F64, angular_velocity_deg_s: tuple[float, float, float], time_s: F64) -> F64:
    """Each point turned by the rotation omega * t of its own time (Rodrigues' formula).

    Args:
        xyz: (N, 3) float64. angular_velocity_deg_s: (3,) deg/s. time_s: (N,) s.

    Returns:
        (N, 3) float64: R(omega t_i) x_i.
    """
    omega = np.radians(np.asarray(angular_velocity_deg_s, dtype=np.float64))
    rate = float(np.linalg.norm(omega))
    if rate == 0.0:
        return xyz.copy()
    kx, ky, kz = (float(v) for v in omega / rate)
    angle = rate * time_s
    cos, sin = np.cos(angle), np.sin(angle)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    along = (x * kx + y * ky + z * kz) * (1.0 - cos)
    out = np.empty_like(xyz)
    # R v = v cos + (k x v) sin + k (k . v)(1 - cos), one component at a time
    out[:, 0] = x * cos + (ky * z - kz * y) * sin + kx * along
    out[:, 1] = y * cos + (kz * x - kx * z) * sin + ky * along
    out[:, 2] = z * cos + (kx * y - ky * x) * sin + kz * along
    return out
