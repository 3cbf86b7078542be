"""The markdown sections of a card: the fields that fill dataset_cards/template.md (layout,
generation facts, pipeline stages, physical model, limitations, citation)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from lads.built_tree import trial_subset
from lads.card.kinds import NOT_MODELLED_BY_KIND, WEATHER_STAGES, kind_fields, variant_kind
from lads.card.sources import REALITY, Source

NOT_MODELLED = (
    "single return only: one return per beam (strongest or last), no dual-return output",
    "no multiple scattering: particles act through extinction and single backscatter only",
    "no wet-road spray, splashes or standing water, and no change of surface reflectance "
    "from wetness or snow cover (accumulated snow)",
    "no droplets, ice or dirt on the sensor window",
    "no correlation of particles between consecutive scans (each scan draws its own)",
    "no effect on cameras or other sensors of the source dataset",
)
# How a sensor transfer's scene is made, with a window and with the frame alone.
WINDOW_WORDS = "the returns of a window of source scans, placed with the sequence's poses,"
ALONE_WORDS = "the returns of the frame's own scan (neighbours 0: no other scan, no poses),"
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
    "sensor": f"sensor: {WINDOW_WORDS} become surfels (ellipses in the surface plane "
    "carrying label and albedo); the "
    "target's beams (its elevations, azimuth step, range limits) are ray-cast against them "
    "from the frame's pose, depths blended over the beam's footprint, returns kept where the "
    "target's detector sees them (a surface is never taken as fainter than the source's own "
    "detection of it implies), its range noise added, intensity in its encoding. Moving "
    "classes and moved instances come from the frame's own scan only.",
    "intensity": "intensity: a learned generator predicts every point's intensity from range, "
    "incidence and material (docs/intensity.md of lads).",
    "wet_ground": "wet ground: a water film on the classes marked as ground; Fresnel "
    "reflection at its surface, absorption and internal reflection darken the road, most at "
    "grazing incidence, and returns that fall below the detection limit are lost.",
    "beam_missing": "beam missing: a share of the sensor's lasers fails for the whole scan "
    "(drawn per scan unless fixed); every return of a failed laser is lost, nothing else "
    "changes.",
    "motion_distortion": "motion distortion: each point is reported in the sensor pose of "
    "the moment it was measured (its azimuth's time in the sweep), the vehicle moving at the "
    "given speed and turn rate, as an uncompensated sweep would; the seam behind the vehicle "
    "opens by speed x sweep period.",
    "incomplete_echo": "incomplete echo: the classes whose material has a clear-coat finish "
    "(vehicle paint) are repainted with a darker paint; their returns dim by the reflectance "
    "ratio and are lost where the sensor's detection limit then misses them, far ones first.",
    "crosstalk": "crosstalk: a share of the beams catches the pulses of an unsynchronised LiDAR "
    "nearby; each reports a false return on its own ray at a range uniform over the range "
    "gate (the pulse's timing), with an intensity of unknown power.",
}


# The arrays of a provenance group, for the card's Provenance section.
PROVENANCE_ARRAYS = {
    "other": "`source_index` (int64, the source row of each output point) and `outcome` "
    "(uint8: 0 kept, 1 attenuated, 2 particle, 3 lost, the last in aligned mode only, 5 "
    "displaced by the vehicle's motion).",
    "resampled": "`source_index` (int64, the row of the source return whose surface each "
    "beam hit), `source_scan` (int16, which scan of the frame's window that row is in; the "
    "group's `window` attribute lists the window's scan paths) and `outcome` (uint8, 4: "
    "a beam of the target sensor).",
}
POINTS_MODE_TEXT = {
    "physical": "Lost beams are removed and particle returns stay where the particle was; "
    "label files are rewritten to match (particle returns get the particle label). Output "
    "order follows source order, so output files may have fewer or more points than the "
    "source.",
    "aligned": "Point count and order are unchanged and label files are byte-identical to the "
    "source. Lost beams sit at the sensor origin with intensity 0; particle returns keep "
    "their source label.",
    "resampled": "Every point is a beam of the target sensor, in its order; label files are "
    "rewritten to match (the label of the surface each beam hit), so a file's point count is "
    "the target's, not the source's.",
}


def fields(
    run: dict[str, Any],
    rows: list[dict[str, Any]],
    ok: list[dict[str, Any]],
    src: Source,
    splits: list[dict[str, Any]],
    pipeline_text: str,
    figures: list[str] | tuple[str, ...],
) -> dict[str, str]:
    """The values of the ${...} placeholders of dataset_cards/template.md."""
    total = sum(int(o.get("bytes", 0)) for r in ok for o in r.get("outputs", []))
    mode = str(run.get("points_mode", "unknown"))
    kind = variant_kind([name for name, _ in pipeline_stages(pipeline_text)])
    texts = kind_fields(kind, src.pretty)
    return {
        **texts,
        "pretty_name": f"LADS {src.pretty}: {run.get('variant', 'variant')}",
        "summary": f"`{run.get('variant', '?')}`, a {texts['kind_word']} variant of "
        f"{src.pretty} built by lads: {_coverage(run, len(ok))}, in {_record_words(run)} and "
        "the source's folder layout.",
        "description": _description(run, src),
        "format_text": _format_text(run),
        "provenance_arrays": PROVENANCE_ARRAYS["resampled" if mode == "resampled" else "other"],
        "lads_version": str(run.get("lads_version", "?")),
        "source_pretty": src.pretty,
        "source": str(run.get("source", "?")),
        "variant": str(run.get("variant", "?")),
        "items": str(len(ok)),
        "failed": str(len(rows) - len(ok)),
        "total_size": f"{_human(total)} of item files",
        "license_text": src.license_text,
        "source_link": src.link,
        # None: lads ran from an installed package, whose version then names the code.
        "git_commit": str(run.get("git_commit") or "none (installed package)"),
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
        "not_modelled": "\n".join(
            f"- {line}" for line in NOT_MODELLED_BY_KIND.get(kind, NOT_MODELLED)
        ),
        "figures": "\n".join(f"![{Path(f).stem}]({f})" for f in figures),
        "citation": "\n".join(c for c in (src.citation, REALITY) if c),
    }


def _coverage(run: dict[str, Any], built: int) -> str:
    """Which source scans the tree holds: every one, or a --limit trial's subset."""
    subset = trial_subset(run)
    if subset is None:
        return "every source scan once"
    return (
        f"a trial subset (`--limit {run['limit']}`), {built} of the source's {subset[1]} "
        "scans, each once"
    )


def _description(run: dict[str, Any], src: Source) -> str:
    copied = [c.get("path", "?") for c in run.get("copied_files") or [] if isinstance(c, dict)]
    names = sorted({Path(str(p)).name for p in copied})
    side = (
        f"The source's other files ({len(copied)}: {', '.join(names[:6])}"
        f"{', ...' if len(names) > 6 else ''}) are copied unchanged."
        if copied
        else "The source has no calibration, pose or table files to copy."
    )
    return (
        f"Each scan of {src.pretty} was passed through the lads pipeline of variant "
        f"`{run.get('variant', '?')}` (sensor profile `{run.get('sensor', '?')}`, root seed "
        f"{run.get('seed', '?')}); the result is written at the scan's own relative path in "
        f"{_record_words(run)}. {side}"
    )


def _format_text(run: dict[str, Any]) -> str:
    """What a loader of the tree needs: the source's own record, or the target's."""
    if _native_record(run):
        return (
            "Every file has the source's format, name and folder, so the source dataset's "
            "loaders, calibration, poses and label maps work unchanged."
        )
    columns = ", ".join(str(c) for c in run.get("point_columns") or []) or "see run.json"
    return (
        "Every file has the source's name and folder, so calibration, poses and label maps "
        "work unchanged; the scan files hold the target sensor's own point record (float32 "
        f"{columns}; `point_columns` in run.json), so a loader must read that record instead "
        "of the source's."
    )


def _record_words(run: dict[str, Any]) -> str:
    """The point record of the tree's scans in words: the source format's, or (a transfer
    written with --point-format target, or a tree built on one) the sensor's own, with its
    columns."""
    if _native_record(run):
        return "the source's own format"
    columns = ", ".join(str(c) for c in run.get("point_columns") or ())
    return f"the {run.get('sensor', 'target')} sensor's own point record ({columns}, float32)"


def _native_record(run: dict[str, Any]) -> bool:
    """Whether the scans hold the dataset format's own record: the columns its reader
    writes by default (a weather tree built on a target-record transfer keeps that
    transfer's record while its own point_format says "source")."""
    from lads.readers import READERS, reader_class

    columns, source = run.get("point_columns"), run.get("source")
    if not isinstance(columns, list) or source not in READERS:
        return run.get("point_format") != "target"
    return list(reader_class(str(source)).columns) == columns


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
    # Not source_root: the builder's local path means nothing to the card's readers.
    keys = ("lads_version", "git_commit", "config_hash", "seed", "variant", "source",
            "sensor", "points_mode", "point_format", "device")  # fmt: skip
    recorded = {"point_format": "source", **run}  # trees before the setting: the source's
    lines = [f"| {k} | `{recorded.get(k, '?')}` |" for k in keys]
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
        if kind == "sensor" and params.get("neighbours") == 0:
            text = text.replace(WINDOW_WORDS, ALONE_WORDS)
        lines.append(f"- `{name}` ({shown}): {text}")
    if any(name in WEATHER_STAGES for name, _ in pipeline_stages(pipeline_text)):
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
