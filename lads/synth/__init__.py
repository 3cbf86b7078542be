"""Procedural synthetic LiDAR datasets: a seeded street ray-cast for any sensor profile.

`synth_frames` yields frames in memory; `write_synthetic_dataset` writes them as a
SemanticKITTI, nuScenes-lidarseg or Voxelscape tree. The CLI command is
`lads.synth.command.synth_command`.
"""

from lads.synth.frames import SynthFrame, synth_frame, synth_frames
from lads.synth.writer import LAYOUTS, SynthSummary, write_synthetic_dataset

__all__ = [
    "LAYOUTS",
    "SynthFrame",
    "SynthSummary",
    "synth_frame",
    "synth_frames",
    "write_synthetic_dataset",
]
