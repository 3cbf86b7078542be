"""What the geometric ground fit calls ground on labelled real SemanticKITTI frames: the share
of road-like classes, terrain and vegetation among its points, and their median remission
(docs/augment.md §2.4: why all fitted ground is taken as asphalt).

    python tools/fitted_ground_classes.py [DATA]

DATA holds semantickitti*/sequences/*/{velodyne,labels}; default ../shared/data.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lads.physics.ground_fit import ground_mask
from lads.physics.materials import class_ids, class_roles

TERRAIN, VEGETATION = 72, 70  # SemanticKITTI ids


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", type=Path, default=Path("../shared/data"))
    args = parser.parse_args()
    road_like = sorted(class_roles("semantickitti").road_like)
    print("frame | fitted points | road-like | terrain | vegetation | remission road / terrain")
    for scan in sorted(args.data.glob("semantickitti*/sequences/*/velodyne/*.bin")):
        label_file = scan.parent.parent / "labels" / f"{scan.stem}.label"
        points = np.fromfile(scan, "<f4").reshape(-1, 4)
        if not label_file.is_file() or len(points) < 1000:
            continue
        labels = class_ids(np.fromfile(label_file, "<u4"), "semantickitti")
        fitted = ground_mask(points[:, :3])
        share = {
            name: float(np.mean(np.isin(labels[fitted], ids)))
            for name, ids in (("road", road_like), ("terrain", [TERRAIN]), ("veg", [VEGETATION]))
        }
        remission = points[:, 3]
        road = np.median(remission[fitted & np.isin(labels, road_like)])
        terrain_rows = fitted & (labels == TERRAIN)
        terrain = f"{np.median(remission[terrain_rows]):.2f}" if terrain_rows.any() else "-"
        print(
            f"{scan.relative_to(args.data)} | {int(fitted.sum())} | {share['road']:.2f} | "
            f"{share['terrain']:.2f} | {share['veg']:.2f} | {road:.2f} / {terrain}"
        )


if __name__ == "__main__":
    main()
