"""Corruptions for training loops: weather and sensor faults applied to in-memory point clouds
(docs/augment.md).

- `corrupt(points, labels, instance, rng, corruption=..., severity=..., sensor=...)`: one call.
- `Corruption(...)`: configured once, applied per sample with randomness from
  (seed, sample id, epoch).
- `CORRUPTIONS`: the suite, by name; severities "light", "moderate", "heavy".
- `ego_motion_from_poses(times_s, poses, index, where)`: a sample's `EgoMotion` from the
  poses of its neighbouring scans, for motion distortion at the recorded motion
  (`corrupt(..., corruption="motion_distortion", **motion.params())`).
- Loader adapters, each imported on demand so the core never imports torch or a framework:
  `lads.augment.torch_data` (Dataset wrapper, worker init), `lads.augment.mmdet3d`
  (a registered transform), `lads.augment.openpcdet` (a DataAugmentor entry).
"""

from lads.augment.core import Augmented, AugmentInfo, Corruption, corrupt
from lads.corruptions import CORRUPTIONS, CorruptionSpec, corruption_spec
from lads.physics.ego_motion import EgoMotion
from lads.physics.ego_motion import from_poses as ego_motion_from_poses
from lads.physics.severity import SEVERITIES
from lads.seeding import augment_rng

__all__ = [
    "CORRUPTIONS",
    "SEVERITIES",
    "AugmentInfo",
    "Augmented",
    "Corruption",
    "CorruptionSpec",
    "EgoMotion",
    "augment_rng",
    "corrupt",
    "corruption_spec",
    "ego_motion_from_poses",
]
