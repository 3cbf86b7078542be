"""The card's YAML front matter: offline copies of the Hub's enums and the metadata block
rendered from run.json, the source facts and the splits."""

from __future__ import annotations

from typing import Any

import yaml

from lads.card.sections import PHYSICS
from lads.card.sources import CONFIRM, SOURCES, Source

TAGS = ["lidar", "point-cloud", "autonomous-driving", "synthetic"]
# The tag of each kind of variant (lads.card.kinds.variant_kind).
KIND_TAGS = {"weather": "weather-augmentation", "sensor": "sensor-adaptation",
             "intensity": "intensity-adaptation", "corruption": "robustness-benchmark"}  # fmt: skip

# Offline copies of the Hub's enums (hub-docs datasetcard.md, repositories-licenses.md,
# huggingface.js tasks); only these values pass `validate_card`.
LICENSES = frozenset(
    "apache-2.0 mit openrail bigscience-openrail-m creativeml-openrail-m "
    "bigscience-bloom-rail-1.0 bigcode-openrail-m afl-3.0 artistic-2.0 bsl-1.0 bsd "
    "bsd-2-clause bsd-3-clause bsd-3-clause-clear c-uda cc cc0-1.0 cc-by-2.0 cc-by-2.5 "
    "cc-by-3.0 cc-by-4.0 cc-by-sa-3.0 cc-by-sa-4.0 cc-by-nc-2.0 cc-by-nc-3.0 cc-by-nc-4.0 "
    "cc-by-nd-4.0 cc-by-nc-nd-3.0 cc-by-nc-nd-4.0 cc-by-nc-sa-2.0 cc-by-nc-sa-3.0 "
    "cc-by-nc-sa-4.0 cdla-sharing-1.0 cdla-permissive-1.0 cdla-permissive-2.0 wtfpl ecl-2.0 "
    "epl-1.0 epl-2.0 etalab-2.0 eupl-1.1 eupl-1.2 agpl-3.0 gfdl gpl gpl-2.0 gpl-3.0 lgpl "
    "lgpl-2.1 lgpl-3.0 isc h-research intel-research lppl-1.3c ms-pl apple-ascl mpl-2.0 "
    "odc-by odbl openrail++ osl-3.0 postgresql ofl-1.1 ncsa unlicense zlib pddl lgpl-lr "
    "unknown other".split()
)
SIZE_CATEGORIES = (
    "n<1K", "1K<n<10K", "10K<n<100K", "100K<n<1M", "1M<n<10M", "10M<n<100M",
    "100M<n<1B", "1B<n<10B", "10B<n<100B", "100B<n<1T", "n>1T",
)  # fmt: skip
ANNOTATION_CREATORS = frozenset(
    {"found", "crowdsourced", "expert-generated", "machine-generated", "no-annotation", "other"}
)
TASK_IDS = {
    "image-segmentation": {
        "semantic-segmentation",
        "instance-segmentation",
        "panoptic-segmentation",
    },
    "object-detection": {"face-detection", "vehicle-detection"},
    "depth-estimation": set(),
    "robotics": set(),
    "other": set(),
}
FRONT_MATTER_KEYS = frozenset(
    "language license license_name license_link license_details tags annotations_creators "
    "language_creators language_details pretty_name size_categories source_datasets "
    "task_categories task_ids paperswithcode_id configs dataset_info viewer "
    "train-eval-index".split()
)


def size_category(n: int) -> str:
    """The Hub's size_categories value for n examples."""
    for i, category in enumerate(SIZE_CATEGORIES[:-1]):
        if n < 10 ** (i + 3):
            return category
    return SIZE_CATEGORIES[-1]


def render_front_matter(
    run: dict[str, Any],
    src: Source,
    n_ok: int,
    splits: list[dict[str, Any]],
    kind: str = "weather",
) -> str:
    """The YAML front matter (without the '---' lines), with a note on the inherited licence."""
    synthetic = src is SOURCES["synthetic"]
    copied = sum(int(c.get("bytes", 0)) for c in run.get("copied_files") or [])
    meta: dict[str, Any] = {
        "pretty_name": f"LADS {src.pretty} - {run.get('variant', 'variant')}",
        "license": src.license,
        "license_name": src.license_name,
        "license_link": src.license_link,
        "tags": [*TAGS[:3], KIND_TAGS[kind], *TAGS[3:]]
        + [s for s in PHYSICS if s in str(run.get("variant", ""))],
        "annotations_creators": ["machine-generated" if synthetic else "expert-generated"],
        "size_categories": [size_category(n_ok)],
        "source_datasets": ["original"] if not src.hf_id else [f"extended|{src.hf_id}"],
        "task_categories": ["image-segmentation"],
        "task_ids": ["semantic-segmentation"],
        "dataset_info": {
            "splits": splits,
            "dataset_size": sum(s["num_bytes"] for s in splits) + copied,
        },
    }
    if not src.license_link:
        del meta["license_link"]
    text = yaml.safe_dump(meta, sort_keys=False, allow_unicode=True, width=100)
    note = f"# licence inherited from {src.pretty}: {CONFIRM}\n"
    return text.replace("license_name:", note + "license_name:", 1)
