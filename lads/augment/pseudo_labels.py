"""Per-point classes from geometry, for data without point labels (detection data):
- from 3D boxes (OpenPCDet's gt_boxes, mmdetection3d's gt_bboxes_3d): incomplete echo finds
  the vehicles' clear-coat points through them;
- from the ground fit (`lads.physics.ground_fit`): wet ground finds the road.
(docs/augment.md §2.)

The classes come out as SemanticKITTI ids (car inside a vehicle box, road on the fitted
ground, unlabeled elsewhere), so the corruption reads the `semantickitti` materials.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import AugmentInputError
from lads.physics.ground_fit import ground_mask

# Detection class names (KITTI, nuScenes, Waymo, as the frameworks spell them) whose boxes
# hold painted vehicle bodies.
VEHICLE_NAMES = frozenset(
    {"Car", "Van", "Truck", "Tram", "Bus", "car", "truck", "bus", "trailer",
     "construction_vehicle", "Vehicle", "vehicle"}
)  # fmt: skip
# The label set the box classes are written in, and its ids for a car and for nothing.
PSEUDO_LABEL_SET = "semantickitti"
CAR_ID, ROAD_ID, UNLABELED_ID = 10, 40, 0


def points_in_boxes(
    xyz: npt.NDArray[np.floating[Any]], boxes: npt.NDArray[np.floating[Any]]
) -> npt.NDArray[np.bool_]:
    """Whether each point lies inside any of the boxes.

    Args:
        xyz: (N, 3) points, m.
        boxes: (B, >= 7) x, y, z of the box centre, dx, dy, dz (length, width, height), m,
            and heading about z, rad (OpenPCDet's layout; further columns ignored).

    Returns:
        (N,) bool.

    Raises:
        AugmentInputError: boxes not (B, >= 7).
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.ndim != 2 or (boxes.size and boxes.shape[1] < 7):
        raise AugmentInputError(
            f"boxes have shape {boxes.shape}; expected (B, 7+): x, y, z (centre), dx, dy, dz, "
            "heading."
        )
    inside = np.zeros(len(xyz), dtype=bool)
    p = np.asarray(xyz, dtype=np.float64)
    for x, y, z, dx, dy, dz, heading in boxes[:, :7]:
        rel = p - (x, y, z)
        cos, sin = np.cos(heading), np.sin(heading)
        along = rel[:, 0] * cos + rel[:, 1] * sin
        across = -rel[:, 0] * sin + rel[:, 1] * cos
        upright = np.abs(rel[:, 2]) <= dz / 2
        inside |= (np.abs(along) <= dx / 2) & (np.abs(across) <= dy / 2) & upright
    return inside


def vehicle_labels(
    xyz: npt.NDArray[np.floating[Any]],
    boxes: npt.NDArray[np.floating[Any]],
    is_vehicle: npt.ArrayLike,
) -> npt.NDArray[np.uint32]:
    """(N,) SemanticKITTI ids: car inside a vehicle box, unlabeled elsewhere.

    Args:
        xyz: (N, 3) m. boxes: (B, >= 7) as `points_in_boxes`.
        is_vehicle: (B,) bool, which boxes hold vehicles.
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return np.full(len(xyz), UNLABELED_ID, dtype=np.uint32)
    inside = points_in_boxes(xyz, boxes[np.asarray(is_vehicle, dtype=bool)])
    return np.where(inside, CAR_ID, UNLABELED_ID).astype(np.uint32)


def ground_labels(xyz: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.uint32]:
    """(N,) SemanticKITTI ids: road on the fitted ground (`lads.physics.ground_fit`, whose
    ground also holds terrain: asphalt is assumed for all of it), unlabeled elsewhere."""
    return np.where(ground_mask(xyz), ROAD_ID, UNLABELED_ID).astype(np.uint32)
