"""Hugging Face dataset card (README.md) of a built variant tree.

`render_card` reads the tree's run.json, manifest.jsonl and pipeline.yaml and fills
dataset_cards/template.md under YAML front matter (style.md §3): the licence is inherited
from the source (never more permissive), sizes and splits come from the manifest.
`validate_card` checks the front matter's enums offline (the Hub's validator is an online
API). The card is part of the tree: the runner writes it before SHA256SUMS, and
`write_card` never touches SHA256SUMS.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from string import Template
from typing import Any

import yaml

from lads.errors import ManifestError

card_name = "README.md"
CARD_NAME = card_name
TEMPLATE = Path(__file__).resolve().parents[1] / "dataset_cards" / "template.md"
TAGS = ["lidar", "point-cloud", "autonomous-driving", "weather-augmentation", "synthetic"]
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


_REALITY = """@misc{anand_reality_lads,
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
_VOXELSCAPE = """@article{saleh_voxelscape,
  author  = {Saleh, K. and Hossny, M. and others},
  title   = {{VoxelScape: Large Scale Simulated 3D Point Cloud Dataset of Urban Traffic
             Environments}},
  journal = {IEEE Transactions on Intelligent Transportation Systems},
  note    = {venue and year unverified}
}"""
SOURCES: dict[str, Source] = {
    "semantickitti": Source(
        "SemanticKITTI", "semantic_kitti", "cc-by-nc-sa-4.0", "cc-by-nc-sa-4.0", NC_SA,
        "CC BY-NC-SA 4.0 (SemanticKITTI labels; the KITTI Odometry scans are CC BY-NC-SA "
        f"3.0), non-commercial share-alike, inherited from the source; {CONFIRM}",
        "http://www.semantic-kitti.org/", _KITTI,
    ),
    "nuscenes": Source(
        "nuScenes-lidarseg", "nuscenes", "cc-by-nc-sa-4.0", "cc-by-nc-sa-4.0-and-nuscenes-terms",
        "https://www.nuscenes.org/terms-of-use",
        "CC BY-NC-SA 4.0 plus the nuScenes Terms of Use, non-commercial share-alike, "
        f"inherited from the source; {CONFIRM}",
        "https://www.nuscenes.org/", _NUSCENES,
    ),
    "wads": Source(
        "WADS", "wads", "cc-by-nc-sa-4.0", "cc-by-nc-sa-4.0", NC_SA,
        f"CC BY-NC-SA 4.0, non-commercial share-alike, inherited from the source; {CONFIRM}",
        "Winter Adverse Driving dataSet, Michigan Technological University", _WADS,
    ),
    "voxelscape": Source(
        "VoxelScape", "voxelscape", "other", "voxelscape-data-terms-unknown",
        "https://voxel-scape.github.io/dataset",
        "unknown: the VoxelScape data licence has not been checked (its devkit is MIT); "
        f"{CONFIRM}, and do not publish until it is known",
        "https://voxel-scape.github.io/dataset", _VOXELSCAPE,
    ),
    "synthetic": Source(
        "lads synthetic street scans", "", "apache-2.0", "apache-2.0",
        "https://www.apache.org/licenses/LICENSE-2.0",
        "Apache-2.0 (lads' own licence): the scans are ray-cast by lads, no external data",
        "lads.synthetic (generated, no external data)", "",
    ),
}  # fmt: skip
UNKNOWN_SOURCE = Source(
    "an unknown source", "", "other", "unknown", "", f"unknown; {CONFIRM}", "unknown", ""
)

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
REQUIRED_SECTIONS = (
    "Dataset Details", "Uses", "Dataset Structure", "Generation",
    "Physical model and limitations", "Verification", "Bias, Risks, and Limitations", "Citation",
)  # fmt: skip
NOT_MODELLED = (
    "single return only: one return per beam (strongest or last), no dual-return output",
    "no multiple scattering: particles act through extinction and single backscatter only",
    "no wet-road spray, splashes or standing water, and no change of surface reflectance "
    "from wetness or snow cover (accumulated snow)",
    "no droplets, ice or dirt on the sensor window",
    "no correlation of particles between consecutive scans (each scan draws its own)",
    "no effect on cameras or other sensors of the source dataset",
)
PHYSICS = {
    "rain": "rain: Marshall-Palmer drop sizes, water Mie extinction and Fresnel backscatter; "
    "per-beam Monte Carlo of the drops in the beam, sampled exactly as a thinned Poisson "
    "process. No real rain recording was available to calibrate the drop reflectivity.",
    "snow": "snow: Gunn-Marshall melted diameters widened to flakes of 0.1 g/cm3, ice Mie "
    "extinction; flake reflectivity, beam divergence and the near-range onset of faint "
    "returns fitted to real falling snow (WADS) at an assumed rate.",
    "fog": "fog: extinction from the meteorological optical range (visibility), hard-target "
    "attenuation exp(-2 alpha R) and the soft volume return of the fog itself (Mie lidar "
    "ratio of advection-fog droplets, about 17 sr).",
}


def render_card(out_root: Path, *, figures: list[str] | tuple[str, ...] = ()) -> str:
    """The card text of a built tree: YAML front matter, then the filled template.

    Args:
        out_root: the built tree (run.json, manifest.jsonl, pipeline.yaml are read).
        figures: image paths relative to out_root to embed (e.g. "figures/range.png").

    Raises:
        ManifestError: run.json or manifest.jsonl is missing or not JSON.
    """
    out_root = Path(out_root)
    run = _read_json(out_root / "run.json")
    rows = _read_manifest(out_root / "manifest.jsonl")
    pipeline_text = _read_text(out_root / "pipeline.yaml")
    src = source_info(run, out_root)
    ok = [r for r in rows if r.get("status") == "ok"]
    splits = _splits(run, ok, src)
    front = _front_matter(run, src, len(ok), splits)
    fields = _fields(run, rows, ok, src, splits, pipeline_text, figures)
    body = Template(TEMPLATE.read_text()).substitute(fields)
    return f"---\n{front}---\n\n" + re.sub(r"\n{3,}", "\n\n", body)


def write_card(out_root: Path, *, figures: list[str] | tuple[str, ...] = ()) -> Path:
    """Render the card and write OUT/README.md atomically (tmp + rename); SHA256SUMS is
    left alone (the runner writes the card first, then the checksums)."""
    path = Path(out_root) / card_name
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(render_card(out_root, figures=figures))
    os.replace(tmp, path)
    return path


def source_info(run: dict[str, Any], out_root: Path | None = None) -> Source:
    """The source facts of a tree. Synthetic when run.json's source or source_root says so,
    or when the tree sits in a `make demo` folder (marked by lads.demo.MARKER)."""
    name = str(run.get("source", ""))
    root_parts = Path(str(run.get("source_root", ""))).parts
    in_demo = out_root is not None and (Path(out_root).parent / DEMO_MARKER).is_file()
    if name == "synthetic" or in_demo or any("synthetic" in p.lower() for p in root_parts):
        return SOURCES["synthetic"]
    return SOURCES.get(name, UNKNOWN_SOURCE)


def size_category(n: int) -> str:
    """The Hub's size_categories value for n examples."""
    for i, category in enumerate(SIZE_CATEGORIES[:-1]):
        if n < 10 ** (i + 3):
            return category
    return SIZE_CATEGORIES[-1]


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ManifestError(f"{path}: cannot read ({exc}); a card needs a built tree.") from exc
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: expected a JSON object; rebuild the tree.")
    return data


def _read_manifest(path: Path) -> list[dict[str, Any]]:
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as exc:
        raise ManifestError(f"{path}: cannot read ({exc}); a card needs a built tree.") from exc


def _read_text(path: Path) -> str:
    return path.read_text() if path.is_file() else "# pipeline.yaml missing from the tree\n"


def _splits(run: dict[str, Any], ok: list[dict[str, Any]], src: Source) -> list[dict[str, Any]]:
    """Splits from the source inventory's groups (SemanticKITTI train/validation/test,
    nuScenes version), else one split "full"; bytes and counts from the manifest."""
    totals: dict[str, list[int]] = {}
    names = _split_names(run, ok) if src.hf_id else {}
    for row in ok:
        entry = totals.setdefault(names.get(str(row.get("item_id")), "full"), [0, 0])
        entry[0] += sum(int(o.get("bytes", 0)) for o in row.get("outputs", []))
        entry[1] += 1
    return [{"name": k, "num_bytes": v[0], "num_examples": v[1]} for k, v in sorted(totals.items())]


def _split_names(run: dict[str, Any], ok: list[dict[str, Any]]) -> dict[str, str]:
    from lads import inventory

    name = str(run.get("source", ""))
    if name not in inventory.available():
        return {}
    inv = inventory.load_inventory(name)
    version = inventory.tree_version(
        run, [o.get("path", "") for r in ok for o in r.get("outputs", [])]
    )
    out = {}
    for row in ok:
        item_id = str(row.get("item_id"))
        group = inventory.group_of(item_id, inv.group_by, version=version)
        spec = inv.groups.get(group or "")
        if group is None and inv.group_by == "nuscenes_version":
            out[item_id] = "sweeps"
        elif spec is not None and spec.split:
            out[item_id] = re.sub(r"\W", "_", spec.split)
    return out


def _front_matter(run: dict[str, Any], src: Source, n_ok: int, splits: list[dict[str, Any]]) -> str:
    synthetic = src is SOURCES["synthetic"]
    copied = sum(int(c.get("bytes", 0)) for c in run.get("copied_files") or [])
    meta: dict[str, Any] = {
        "pretty_name": f"LADS {src.pretty} - {run.get('variant', 'variant')}",
        "license": src.license,
        "license_name": src.license_name,
        "license_link": src.license_link,
        "tags": TAGS + [s for s in PHYSICS if s in str(run.get("variant", ""))],
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


def _fields(
    run: dict[str, Any],
    rows: list[dict[str, Any]],
    ok: list[dict[str, Any]],
    src: Source,
    splits: list[dict[str, Any]],
    pipeline_text: str,
    figures: list[str] | tuple[str, ...],
) -> dict[str, str]:
    total = sum(int(o.get("bytes", 0)) for r in ok for o in r.get("outputs", []))
    mode = str(run.get("points_mode", "unknown"))
    return {
        "pretty_name": f"LADS {src.pretty}: {run.get('variant', 'variant')}",
        "summary": f"`{run.get('variant', '?')}`, a weather variant of {src.pretty} built by "
        "lads: every source scan once, in the source's own format and folder layout.",
        "description": _description(run, src),
        "lads_version": str(run.get("lads_version", "?")),
        "source_pretty": src.pretty,
        "source": str(run.get("source", "?")),
        "variant": str(run.get("variant", "?")),
        "items": str(len(ok)),
        "failed": str(len(rows) - len(ok)),
        "total_size": f"{_human(total)} of item files",
        "license_text": src.license_text,
        "source_link": src.link,
        "git_commit": str(run.get("git_commit", "?")),
        "layout": _layout(ok, run),
        "points_mode": mode,
        "points_mode_text": POINTS_MODE_TEXT.get(mode, "Not recorded in run.json."),
        "splits_table": _table(
            ["split", "examples", "bytes"],
            [[s["name"], s["num_examples"], s["num_bytes"]] for s in splits],
        ),
        "annotations_creators": "generated by lads" if src.hf_id == "" else "expert-generated",
        "generation_table": _generation(run),
        "stages_table": _stages_table(ok, pipeline_text),
        "pipeline_yaml": pipeline_text.rstrip("\n"),
        "physics_text": _physics(run, pipeline_text),
        "not_modelled": "\n".join(f"- {line}" for line in NOT_MODELLED),
        "figures": "\n".join(f"![{Path(f).stem}]({f})" for f in figures),
        "citation": "\n".join(c for c in (src.citation, _REALITY) if c),
    }


POINTS_MODE_TEXT = {
    "physical": "Lost beams are removed and particle returns stay where the particle was; "
    "label files are rewritten to match (particle returns get the particle label). Output "
    "order follows source order, so output files may have fewer or more points than the "
    "source.",
    "aligned": "Point count and order are unchanged and label files are byte-identical to the "
    "source. Lost beams sit at the sensor origin with intensity 0; particle returns keep "
    "their source label.",
}


def _description(run: dict[str, Any], src: Source) -> str:
    return (
        f"Each scan of {src.pretty} was passed through the lads pipeline of variant "
        f"`{run.get('variant', '?')}` (sensor profile `{run.get('sensor', '?')}`, root seed "
        f"{run.get('seed', '?')}); the result is written at the scan's own relative path in "
        "the source format. Calibration, poses, timestamps and tables are copied unchanged."
    )


def _layout(ok: list[dict[str, Any]], run: dict[str, Any]) -> str:
    roles: dict[str, list[Any]] = {}
    for row in ok:
        for o in row.get("outputs", []):
            entry = roles.setdefault(str(o.get("role")), [0, 0, o.get("record_bytes"), o["path"]])
            entry[0] += 1
            entry[1] += int(o.get("bytes", 0))
    lines = [[f"`{r}`", v[0], v[1], v[2], f"`{v[3]}`"] for r, v in sorted(roles.items())]
    copied = run.get("copied_files") or []
    if copied:
        example = f"`{copied[0].get('path')}`"
        lines.append(
            ["copied", len(copied), sum(int(c.get("bytes", 0)) for c in copied), 0, example]
        )
    table = _table(["role", "files", "bytes", "record bytes", "example"], lines)
    meta = (
        "Also `manifest.jsonl`, `run.json`, `pipeline.yaml`, `provenance.zarr/`, this card, "
        "`SHA256SUMS` and `run_report.json` (timing and failures of the run)."
    )
    return f"Files at the same relative paths as in the source:\n\n{table}\n\n{meta}"


def _generation(run: dict[str, Any]) -> str:
    keys = ("lads_version", "git_commit", "config_hash", "seed", "variant", "source",
            "source_root", "sensor", "points_mode", "device")  # fmt: skip
    lines = [f"| {k} | `{run.get(k, '?')}` |" for k in keys]
    libs = run.get("libraries") or {}
    if isinstance(libs, dict) and libs:
        lines.append(
            "| libraries | " + ", ".join(f"{k} {v}" for k, v in sorted(libs.items())) + " |"
        )
    return "\n".join(lines)


def pipeline_stages(pipeline_text: str) -> list[tuple[str, dict[str, Any]]]:
    """(name, params) of each stage of a pipeline.yaml: entries `{stage: x, k: v, ...}` (as
    lads.config writes them), `{name: x, params: {...}}`, `{x: {...}}` or plain names."""
    try:
        data = yaml.safe_load(pipeline_text)
    except yaml.YAMLError:
        return []
    stages = data.get("stages") if isinstance(data, dict) else None
    out: list[tuple[str, dict[str, Any]]] = []
    for entry in stages if isinstance(stages, list) else []:
        if isinstance(entry, str):
            out.append((entry, {}))
        elif isinstance(entry, dict) and ("name" in entry or "stage" in entry):
            key = "stage" if "stage" in entry else "name"
            params = entry.get("params")
            rest = {k: v for k, v in entry.items() if k != key}
            out.append((str(entry[key]), params if isinstance(params, dict) else rest))
        elif isinstance(entry, dict) and len(entry) == 1:
            ((name, params),) = entry.items()
            out.append((str(name), params if isinstance(params, dict) else {"value": params}))
    return out


def _stages_table(ok: list[dict[str, Any]], pipeline_text: str) -> str:
    params = dict(pipeline_stages(pipeline_text))
    recorded = ok[0].get("stages", []) if ok else []
    rows = []
    for st in recorded if isinstance(recorded, list) else []:
        name = str(st.get("name", "?"))
        shown = ", ".join(f"{k}={v}" for k, v in (params.get(name) or {}).items()) or "defaults"
        rows.append([f"`{name}`", st.get("version", "?"), f"`{st.get('params_hash', '?')}`", shown])
    if not rows:
        rows = [
            [f"`{n}`", "?", "?", ", ".join(f"{k}={v}" for k, v in p.items())]
            for n, p in params.items()
        ]
    return _table(["stage", "version", "params hash", "parameters"], rows)


def _physics(run: dict[str, Any], pipeline_text: str) -> str:
    lines = []
    wavelength = _wavelength(str(run.get("sensor", "")))
    if wavelength:
        lines.append(
            f"Sensor `{run.get('sensor')}` at {wavelength:g} nm, single-beam model "
            "with the profile's beam divergence and range limits.\n"
        )
    for name, params in pipeline_stages(pipeline_text):
        kind = next((k for k in PHYSICS if k in name.lower()), None)
        shown = ", ".join(f"{k}={v}" for k, v in params.items()) or "defaults"
        text = PHYSICS[kind] if kind else f"{name}: see the stage's documentation in lads."
        lines.append(f"- `{name}` ({shown}): {text}")
    lines.append(
        "\nFaint returns (drops, flakes, fog) are suppressed near the sensor by a "
        "transmitter/receiver overlap ramp; bright hard targets still pass at short range."
    )
    return "\n".join(lines)


def _human(n_bytes: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.1f} {unit}"
    return f"{n_bytes} bytes"


def _wavelength(sensor: str) -> float | None:
    try:
        from lads.sensors.profile import load_profile

        return float(load_profile(sensor).wavelength_nm)
    except Exception:  # noqa: BLE001 - the card only omits the line
        return None


def _table(header: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def validate_card(text: str) -> list[str]:
    """Problems of a card's front matter and sections, checked offline against the Hub's
    enums (licence ids, size categories, annotation creators, tasks, split names)."""
    m = re.match(r"^---\n(.*?\n)---\n", text, re.S)
    if not m:
        return ["no YAML front matter ('---' line, YAML, '---' line) at the top"]
    try:
        meta = yaml.safe_load(m.group(1))
    except yaml.YAMLError as exc:
        return [f"front matter is not valid YAML ({exc})"]
    if not isinstance(meta, dict):
        return ["front matter is not a mapping"]
    problems = [f"unknown front-matter key {k!r}" for k in meta if k not in FRONT_MATTER_KEYS]
    problems += _check_license(meta)
    problems += _check_enums(meta)
    problems += _check_dataset_info(meta)
    body = text[m.end() :]
    problems += [
        f"section '## {s}' missing" for s in REQUIRED_SECTIONS if f"\n## {s}" not in "\n" + body
    ]
    return problems


def _check_license(meta: dict[str, Any]) -> list[str]:
    lic = meta.get("license")
    if lic not in LICENSES:
        return [f"license {lic!r} is not a Hub licence id"]
    problems = []
    if lic == "other" and not (meta.get("license_name") and meta.get("license_link")):
        problems.append("license 'other' needs license_name and license_link")
    name = meta.get("license_name")
    if name is not None and not re.fullmatch(r"[a-z0-9][a-z0-9.-]*", str(name)):
        problems.append(f"license_name {name!r} must be a lowercase id (a-z, 0-9, '-', '.')")
    return problems


def _check_enums(meta: dict[str, Any]) -> list[str]:
    problems = []
    checks = (
        ("annotations_creators", ANNOTATION_CREATORS),
        ("size_categories", set(SIZE_CATEGORIES) | {"other"}),
        ("task_categories", set(TASK_IDS)),
    )
    for key, allowed in checks:
        values = meta.get(key, [])
        if not isinstance(values, list) or not values:
            problems.append(f"{key} must be a non-empty list")
            continue
        problems += [
            f"{key}: {v!r} is not one of {sorted(allowed)}" for v in values if v not in allowed
        ]
    ids = set().union(*(TASK_IDS.get(c, set()) for c in meta.get("task_categories") or []))
    problems += [
        f"task_ids: {t!r} does not belong to the task_categories"
        for t in meta.get("task_ids") or []
        if t not in ids
    ]
    for s in meta.get("source_datasets") or []:
        if not re.fullmatch(r"original|extended(\|[\w.-]+)?", str(s)):
            problems.append(f"source_datasets: {s!r} is not 'original' or 'extended|<id>'")
    if not isinstance(meta.get("pretty_name"), str):
        problems.append("pretty_name must be a string")
    if not all(isinstance(t, str) for t in meta.get("tags") or []):
        problems.append("tags must be strings")
    return problems


def _check_dataset_info(meta: dict[str, Any]) -> list[str]:
    info = meta.get("dataset_info")
    if info is None:
        return []
    if not isinstance(info, dict) or not isinstance(info.get("splits"), list):
        return ["dataset_info.splits must be a list"]
    problems = []
    total = 0
    for s in info["splits"]:
        if not isinstance(s, dict) or not re.fullmatch(r"\w+(\.\w+)*", str(s.get("name"))):
            problems.append(
                f"dataset_info.splits: bad split {s!r} (name must match \\w+(\\.\\w+)*)"
            )
            continue
        for key in ("num_bytes", "num_examples"):
            if not isinstance(s.get(key), int) or s[key] < 0:
                problems.append(f"dataset_info.splits[{s['name']}].{key} must be a count >= 0")
        total += s.get("num_examples", 0) if isinstance(s.get("num_examples"), int) else 0
    sizes = meta.get("size_categories") or []
    if info["splits"] and sizes and sizes[0] != "other" and sizes[0] != size_category(total):
        problems.append(
            f"size_categories {sizes} does not fit {total} examples ({size_category(total)})"
        )
    return problems
