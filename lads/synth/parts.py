"""What each surface of the synthetic street is, and its label in every label space.

The generator labels points with its own *part* codes, finer than any dataset's classes
(a curb is not a sidewalk in Voxelscape; a walking kid is a moving person in SemanticKITTI but
a kid in Voxelscape). Each part maps to one SemanticKITTI raw id and one Voxelscape fine
sub-label (lads/synth/voxelscape_ids.yaml), from which the Voxelscape orig class and
kitti_labels id follow.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt


class Part(IntEnum):
    ROAD = 0
    LANE_MARKING = 1
    CROSSWALK = 2
    CURB = 3
    SIDEWALK = 4
    GRASS = 5
    SOIL = 6
    BUILDING_HOUSE = 7
    BUILDING_APARTMENT = 8
    BUILDING_SHOP = 9
    BUILDING_OFFICE = 10
    BUILDING_INDUSTRIAL = 11
    FENCE = 12
    PARKED_CAR = 13
    MOVING_CAR = 14
    ADULT = 15
    WALKING_ADULT = 16
    KID = 17
    WALKING_KID = 18
    LIGHT_POLE = 19
    SIGN_POST = 20
    TRAFFIC_SIGN = 21
    TRUNK = 22
    CROWN = 23
    BUSH = 24


BUILDING_PARTS = (
    Part.BUILDING_HOUSE,
    Part.BUILDING_APARTMENT,
    Part.BUILDING_SHOP,
    Part.BUILDING_OFFICE,
    Part.BUILDING_INDUSTRIAL,
)

# part: (SemanticKITTI raw id, Voxelscape sub-label, reflectance factor on the class material)
_TABLE: dict[Part, tuple[int, int, float]] = {
    Part.ROAD: (40, 421, 1.0),
    Part.LANE_MARKING: (60, 424, 1.0),
    Part.CROSSWALK: (60, 425, 1.0),  # SemanticKITTI paints crosswalks as lane marking
    Part.CURB: (48, 423, 1.0),  # SemanticKITTI has no curb class: it is sidewalk
    Part.SIDEWALK: (48, 422, 1.0),
    Part.GRASS: (72, 931, 1.0),
    Part.SOIL: (72, 411, 0.55),  # bare soil/gravel: 0.30 (gravel) of grass's 0.55
    Part.BUILDING_HOUSE: (50, 301, 1.0),
    Part.BUILDING_APARTMENT: (50, 311, 1.0),
    Part.BUILDING_SHOP: (50, 321, 1.0),
    Part.BUILDING_OFFICE: (50, 331, 1.0),
    Part.BUILDING_INDUSTRIAL: (50, 341, 1.0),
    Part.FENCE: (51, 611, 1.0),
    Part.PARKED_CAR: (10, 111, 1.0),
    Part.MOVING_CAR: (252, 111, 1.0),
    Part.ADULT: (30, 211, 1.0),
    Part.WALKING_ADULT: (254, 211, 1.0),
    Part.KID: (30, 221, 1.0),
    Part.WALKING_KID: (254, 221, 1.0),
    Part.LIGHT_POLE: (80, 511, 1.0),
    Part.SIGN_POST: (80, 512, 1.0),
    Part.TRAFFIC_SIGN: (81, 521, 1.0),
    Part.TRUNK: (71, 911, 1.0),
    Part.CROWN: (70, 912, 1.0),
    Part.BUSH: (70, 921, 1.0),
}

SEMANTICKITTI_OF_PART: npt.NDArray[np.uint32] = np.array(
    [_TABLE[p][0] for p in Part], dtype=np.uint32
)
SUBLABEL_OF_PART: npt.NDArray[np.int32] = np.array([_TABLE[p][1] for p in Part], dtype=np.int32)
RHO_FACTOR_OF_PART: npt.NDArray[np.float32] = np.array(
    [_TABLE[p][2] for p in Part], dtype=np.float32
)
# Parts whose points carry an instance id (things); the generator gives stuff instance 0.
THING_PARTS = (
    Part.PARKED_CAR,
    Part.MOVING_CAR,
    Part.ADULT,
    Part.WALKING_ADULT,
    Part.KID,
    Part.WALKING_KID,
)
# Retro-reflective sheeting returns light towards the source almost independently of the
# incidence angle, so these parts get no cos(incidence) factor.
RETROREFLECTIVE_PARTS = (Part.TRAFFIC_SIGN,)
