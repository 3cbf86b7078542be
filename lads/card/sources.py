"""What a dataset card says about each source dataset: name, Hub id, inherited licence, link
and citation, and how a tree's source is recognised (synthetic sources included)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

NC_SA = "https://creativecommons.org/licenses/by-nc-sa/4.0/"
DEMO_MARKER = "lads_demo.json"  # lads.demo.MARKER, not imported (the demo pulls matplotlib)
CONFIRM = "confirm the source licence on the source's own page before release"


@dataclass(frozen=True, slots=True)
class Source:
    """What a card says about one source dataset."""

    pretty: str
    hf_id: str  # for source_datasets: extended|<hf_id>
    license: str  # a Hub licence id
    license_name: str
    license_link: str
    license_text: str
    link: str
    citation: str


REALITY = """@misc{anand_reality_lads,
  author = {Anand and others},
  title  = {ReaLiTy and LADS},
  note   = {The ReaLiTy/LADS paper; complete title, venue and year from the publication}
}"""
_KITTI = """@inproceedings{behley2019iccv,
  author    = {Behley, J. and Garbade, M. and Milioto, A. and Quenzel, J. and Behnke, S. and
               Stachniss, C. and Gall, J.},
  title     = {{SemanticKITTI: A Dataset for Semantic Scene Understanding of LiDAR Sequences}},
  booktitle = {Proc. of the IEEE/CVF International Conf. on Computer Vision (ICCV)},
  year      = {2019}
}
@inproceedings{geiger2012cvpr,
  author    = {Geiger, Andreas and Lenz, Philip and Urtasun, Raquel},
  title     = {{Are we ready for Autonomous Driving? The KITTI Vision Benchmark Suite}},
  booktitle = {Conference on Computer Vision and Pattern Recognition (CVPR)},
  year      = {2012}
}"""
_NUSCENES = """@inproceedings{caesar2020nuscenes,
  author    = {Caesar, Holger and Bankiti, Varun and Lang, Alex H. and Vora, Sourabh and
               Liong, Venice Erin and Xu, Qiang and Krishnan, Anush and Pan, Yu and
               Baldan, Giancarlo and Beijbom, Oscar},
  title     = {{nuScenes: A multimodal dataset for autonomous driving}},
  booktitle = {CVPR},
  year      = {2020}
}"""
_WADS = """@misc{kurup2021dsor,
  author = {Kurup, Akhil and Bos, Jeremy},
  title  = {{DSOR: A Scalable Statistical Filter for Removing Falling Snow from LiDAR Point
            Clouds in Severe Winter Weather}},
  note   = {arXiv:2109.07078 (introduces WADS)},
  year   = {2021}
}"""
_RADIATE = """@inproceedings{sheeny2021radiate,
  author    = {Sheeny, Marcel and De Pellegrin, Emanuele and Mukherjee, Saptarshi and
               Ahrabian, Alireza and Wang, Sen and Wallace, Andrew},
  title     = {{RADIATE: A Radar Dataset for Automotive Perception in Bad Weather}},
  booktitle = {IEEE International Conference on Robotics and Automation (ICRA)},
  year      = {2021}
}"""
_VOXELSCAPE = """@article{saleh_voxelscape,
  author  = {Saleh, K. and Hossny, M. and others},
  title   = {{VoxelScape: Large Scale Simulated 3D Point Cloud Dataset of Urban Traffic
             Environments}},
  journal = {IEEE Transactions on Intelligent Transportation Systems},
  note    = {venue and year unverified}
}"""
SOURCES: dict[str, Source] = {
    "semantickitti": Source(
        "SemanticKITTI",
        "semantic_kitti",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0",
        NC_SA,
        "CC BY-NC-SA 4.0 (SemanticKITTI labels; the KITTI Odometry scans are CC BY-NC-SA "
        f"3.0), non-commercial share-alike, inherited from the source; {CONFIRM}",
        "http://www.semantic-kitti.org/",
        _KITTI,
    ),
    "nuscenes": Source(
        "nuScenes-lidarseg",
        "nuscenes",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0-and-nuscenes-terms",
        "https://www.nuscenes.org/terms-of-use",
        "CC BY-NC-SA 4.0 plus the nuScenes Terms of Use, non-commercial share-alike, "
        f"inherited from the source; {CONFIRM}",
        "https://www.nuscenes.org/",
        _NUSCENES,
    ),
    "nuscenes-kitti": Source(
        "nuScenes-lidarseg (KITTI-style export)",
        "nuscenes",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0-and-nuscenes-terms",
        "https://www.nuscenes.org/terms-of-use",
        "CC BY-NC-SA 4.0 plus the nuScenes Terms of Use, non-commercial share-alike, "
        f"inherited from the source; {CONFIRM}",
        "https://www.nuscenes.org/",
        _NUSCENES,
    ),
    "nuscenes-scans": Source(
        "nuScenes LIDAR_TOP scans (loose, without tables)",
        "nuscenes",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0-and-nuscenes-terms",
        "https://www.nuscenes.org/terms-of-use",
        "CC BY-NC-SA 4.0 plus the nuScenes Terms of Use, non-commercial share-alike, "
        f"inherited from the source; {CONFIRM}",
        "https://www.nuscenes.org/",
        _NUSCENES,
    ),
    "radiate": Source(
        "RADIATE",
        "radiate",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0",
        NC_SA,
        f"CC BY-NC-SA 4.0, non-commercial share-alike, inherited from the source; {CONFIRM}",
        "http://pro.hw.ac.uk/radiate/",
        _RADIATE,
    ),
    "wads": Source(
        "WADS",
        "wads",
        "cc-by-nc-sa-4.0",
        "cc-by-nc-sa-4.0",
        NC_SA,
        f"CC BY-NC-SA 4.0, non-commercial share-alike, inherited from the source; {CONFIRM}",
        "Winter Adverse Driving dataSet, Michigan Technological University",
        _WADS,
    ),
    "voxelscape": Source(
        "VoxelScape",
        "voxelscape",
        "other",
        "voxelscape-data-terms-unknown",
        "https://voxel-scape.github.io/dataset",
        "unknown: the VoxelScape data licence has not been checked (its devkit is MIT); "
        f"{CONFIRM}, and do not publish until it is known",
        "https://voxel-scape.github.io/dataset",
        _VOXELSCAPE,
    ),
    "synthetic": Source(
        "lads synthetic street scans",
        "",
        "apache-2.0",
        "apache-2.0",
        "https://www.apache.org/licenses/LICENSE-2.0",
        "Apache-2.0 (lads' own licence): the scans are ray-cast by lads, no external data",
        "lads.synth (generated, no external data)",
        "",
    ),
}
UNKNOWN_SOURCE = Source(
    "an unknown source", "", "other", "unknown", "", f"unknown; {CONFIRM}", "unknown", ""
)


def source_info(run: dict[str, Any], out_root: Path | None = None) -> Source:
    """The source facts of a tree. Synthetic when run.json's source or source_root says so,
    or when the tree sits in a `make demo` folder (marked by lads.demo.MARKER)."""
    name = str(run.get("source", ""))
    root_parts = Path(str(run.get("source_root", ""))).parts
    in_demo = out_root is not None and (Path(out_root).parent / DEMO_MARKER).is_file()
    if name == "synthetic" or in_demo or any("synthetic" in p.lower() for p in root_parts):
        return SOURCES["synthetic"]
    return SOURCES.get(name, UNKNOWN_SOURCE)
