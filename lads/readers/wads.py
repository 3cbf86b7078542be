"""WADS (Winter Adverse Driving dataSet, Michigan Tech): real snow in SemanticKITTI layout.

Layout and encodings are SemanticKITTI's (docs/formats.md §4), relative to the folder that holds
`sequences/`:

    sequences/SS/velodyne/NNNNNN.bin     headerless little-endian float32, N x 4:
                                         x, y, z in m, intensity as integer values 0-255
    sequences/SS/labels/NNNNNN.label     headerless little-endian uint32, N; SemanticKITTI ids
                                         plus 110 active falling snow, 111 accumulated snow

About 42 % of the rows of every WADS scan are exact duplicates. They are kept as they are:
labels are matched by index, and a format-preserving writer must not de-duplicate.
"""

from __future__ import annotations

from lads.readers.semantickitti import SemanticKittiReader


class WadsReader(SemanticKittiReader):
    """Reader and encoder of WADS; same options, frames and files as `SemanticKittiReader`.

    Frames: columns ("x", "y", "z", "intensity"); points (N, 4) float32 (intensity 0-255);
    labels (N,) uint32. Particle returns get 110 ("active falling snow").
    """

    name = "wads"
    sensor = "wads64"
    particle_label = 110  # active falling snow
    label_set = "wads"
    scan_what = "WADS scan (N x 4 float32: x, y, z, intensity 0-255)"
    label_what = "WADS labels (uint32 per point)"
