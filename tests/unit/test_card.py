"""Dataset cards: front matter that parses and validates offline, inherited licence, sizes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from lads.card import (
    CARD_NAME,
    card_name,
    pipeline_stages,
    render_card,
    size_category,
    validate_card,
    write_card,
)
from lads.errors import ManifestError
from lads.verify import verify_tree
from tests.fake_trees import build_fake_tree, read_run, write_run, write_sums


def front_matter(text: str) -> dict:
    m = re.match(r"^---\n(.*?\n)---\n", text, re.S)
    assert m, text[:200]
    return yaml.safe_load(m.group(1))


@pytest.fixture
def out(tmp_path: Path) -> Path:
    return build_fake_tree(tmp_path, card=False)[1]


def with_source(out: Path, source: str, **extra) -> Path:
    run = read_run(out)
    run |= {"source": source, **extra}
    write_run(out, run)
    return out


def test_card_front_matter_parses_and_validates(out):
    text = render_card(out)
    meta = front_matter(text)
    assert validate_card(text) == []
    assert meta["license"] == "cc-by-nc-sa-4.0"
    assert meta["license_link"].startswith("https://creativecommons.org/licenses/by-nc-sa/4.0")
    assert meta["source_datasets"] == ["extended|semantic_kitti"]
    assert meta["annotations_creators"] == ["expert-generated"]
    assert meta["task_categories"] == ["image-segmentation"]
    assert meta["task_ids"] == ["semantic-segmentation"]
    assert meta["size_categories"] == ["n<1K"]
    assert "lidar" in meta["tags"] and "snow" in meta["tags"]
    assert "confirm" in text.split("---")[1]  # the licence note sits in the front matter


def test_splits_and_sizes_come_from_the_manifest(out):
    meta = front_matter(render_card(out))
    rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    item_bytes = sum(o["bytes"] for r in rows for o in r["outputs"])
    (split,) = meta["dataset_info"]["splits"]
    assert split == {"name": "train", "num_bytes": item_bytes, "num_examples": 3}
    copied = sum(c["bytes"] for c in read_run(out)["copied_files"])
    assert meta["dataset_info"]["dataset_size"] == item_bytes + copied


def test_validation_split_of_sequence_08(tmp_path):
    out = build_fake_tree(tmp_path, sequence="08", card=False)[1]
    (split,) = front_matter(render_card(out))["dataset_info"]["splits"]
    assert split["name"] == "validation"


@pytest.mark.parametrize(
    ("n", "category"),
    [
        (0, "n<1K"),
        (3, "n<1K"),
        (999, "n<1K"),
        (1000, "1K<n<10K"),
        (23201, "10K<n<100K"),
        (43552, "10K<n<100K"),
        (100_000, "100K<n<1M"),
        (10**13, "n>1T"),
    ],
)
def test_size_category(n, category):
    assert size_category(n) == category


def test_sections_and_generation_facts(out):
    text = render_card(out)
    for section in (
        "Dataset Details",
        "Uses",
        "Dataset Structure",
        "Generation",
        "Physical model and limitations",
        "Verification",
        "Bias, Risks, and Limitations",
        "Citation",
    ):
        assert f"\n## {section}\n" in text
    run = read_run(out)
    assert run["config_hash"] in text and run["git_commit"] in text
    assert "rate_mm_h=10.0" in text and "`snow`" in text
    assert "sha256sum -c SHA256SUMS" in text and "lads verify" in text
    assert "single return only" in text and "spray" in text
    assert "ReaLiTy" in text and "SemanticKITTI" in text
    assert "${" not in text


@pytest.mark.parametrize(
    ("source", "licence", "dataset"),
    [
        ("nuscenes", "cc-by-nc-sa-4.0", "extended|nuscenes"),
        ("wads", "cc-by-nc-sa-4.0", "extended|wads"),
        ("voxelscape", "other", "extended|voxelscape"),
    ],
)
def test_licence_is_inherited(out, source, licence, dataset):
    text = render_card(with_source(out, source))
    meta = front_matter(text)
    assert meta["license"] == licence
    assert meta["source_datasets"] == [dataset]
    assert validate_card(text) == []
    if licence == "other":
        assert meta["license_name"] and meta["license_link"]
        assert "unknown" in text


def test_nuscenes_terms_of_use_are_named(out):
    text = render_card(with_source(out, "nuscenes"))
    assert "nuscenes.org/terms-of-use" in text and "Terms of Use" in text


def test_synthetic_source_uses_the_project_licence(out):
    text = render_card(with_source(out, "semantickitti", source_root="/tmp/synthetic_street"))
    meta = front_matter(text)
    assert meta["license"] == "apache-2.0"
    assert meta["annotations_creators"] == ["machine-generated"]
    assert meta["source_datasets"] == ["original"]
    assert validate_card(text) == []


def test_demo_folder_marks_a_synthetic_source(out):
    (out.parent / "lads_demo.json").write_text("{}\n")
    assert front_matter(render_card(out))["license"] == "apache-2.0"


def test_write_card_is_atomic_and_leaves_sums_alone(out):
    sums_before = (out / "SHA256SUMS").read_bytes()
    path = write_card(out, figures=["figures/range.png"])
    assert path == out / card_name == out / CARD_NAME == out / "README.md"
    assert "![range](figures/range.png)" in path.read_text()
    assert (out / "SHA256SUMS").read_bytes() == sums_before
    assert not list(out.glob("*.tmp"))
    unsummed = verify_tree(out, None)  # the card is not in SHA256SUMS until it is rewritten
    assert [(q.path, q.kind) for q in unsummed.problems] == [("README.md", "extra_file")]
    write_sums(out)
    assert verify_tree(out, None).ok


def test_missing_tree_metadata_raises(tmp_path):
    with pytest.raises(ManifestError, match="run.json"):
        render_card(tmp_path)


@pytest.mark.parametrize(
    ("edit", "complaint"),
    [
        (("license: cc-by-nc-sa-4.0", "license: cc-by-nc-sa"), "Hub licence id"),
        (("- n<1K", "- tiny"), "size_categories"),
        (("- semantic-segmentation", "- depth-estimation"), "task_ids"),
        (("- expert-generated", "- experts"), "annotations_creators"),
        (("- extended|semantic_kitti", "- derived from kitti"), "source_datasets"),
        (("pretty_name:", "prettyname:"), "unknown front-matter key"),
        (("num_examples: 3", "num_examples: 3000"), "size_categories"),
        (("name: train", "name: train split"), "bad split"),
        (("## Citation", "## Cite"), "Citation"),
        (("license_name: cc-by-nc-sa-4.0", "license_name: CC BY NC"), "license_name"),
    ],
)
def test_validate_card_catches_bad_values(out, edit, complaint):
    text = render_card(out)
    assert edit[0] in text
    problems = validate_card(text.replace(edit[0], edit[1], 1))
    assert any(complaint in p for p in problems), problems


def test_validate_card_without_front_matter():
    assert validate_card("# just a heading\n") != []
    assert validate_card("---\n[unclosed\n---\n") != []


def test_pipeline_stage_shapes():
    text = yaml.safe_dump(
        {"stages": [{"stage": "fog", "visibility_m": 50}, {"name": "rain", "params": {"r": 1}},
                    {"snow": {"rate_mm_h": 2}}, "intensity"]}
    )  # fmt: skip
    assert pipeline_stages(text) == [
        ("fog", {"visibility_m": 50}),
        ("rain", {"r": 1}),
        ("snow", {"rate_mm_h": 2}),
        ("intensity", {}),
    ]
    assert pipeline_stages("not: [valid") == []


def test_lads_card_rewrites_the_card_and_its_checksum_line(out):
    from click.testing import CliRunner

    from lads.cli import main

    write_card(out)
    write_sums(out)
    (out / "README.md").write_text("an edited card\n")
    assert not verify_tree(out, None).ok  # the card no longer matches SHA256SUMS
    other_lines = [x for x in (out / "SHA256SUMS").read_text().splitlines() if "README" not in x]
    result = CliRunner().invoke(main, ["card", str(out)])
    assert result.exit_code == 0, result.output
    assert front_matter((out / "README.md").read_text())["license"] == "cc-by-nc-sa-4.0"
    lines = (out / "SHA256SUMS").read_text().splitlines()
    assert [x for x in lines if "README" not in x] == other_lines  # nothing else touched
    assert verify_tree(out, None).ok


def test_lads_card_needs_a_finished_build(out):
    from lads.errors import BuildError
    from lads.finalise import refresh_card

    (out / "SHA256SUMS").unlink()
    with pytest.raises(BuildError, match="finished build"):
        refresh_card(out)
