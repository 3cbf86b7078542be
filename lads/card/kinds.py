"""What kind of variant a card describes (weather, another sensor, a learned intensity) and
the card text that depends on it: uses, rationale, annotations, risks, recommendations."""

from __future__ import annotations

from typing import Any

from lads.stage_params import FAULT_STAGES, WEATHER_STAGES

_TEXT: dict[str, dict[str, str]] = {
    "weather": {
        "word": "weather",
        "direct_use": "Training and evaluating LiDAR semantic segmentation (and other per-point "
        "tasks) under adverse weather: train on this variant, test on {src} or on real "
        "adverse-weather recordings, or use it as a robustness test set.",
        "out_of_scope": "Claims about real sensor behaviour in weather without checking against "
        "real recordings: the weather is simulated (see Physical model and limitations).",
        "rationale": "Real adverse-weather LiDAR data with point labels is scarce. This variant "
        "applies physically modelled weather to every scan of a labelled clear-weather dataset, "
        "one output scan per source scan, so that labels, poses and calibration carry over.",
        "annotations": "Points added by the weather model (particle returns) get the particle "
        "label of the build; removed points take their labels with them (physical mode) or keep "
        "them (aligned mode).",
        "risks": "- The weather is a model fitted to a few real recordings; its particle "
        "statistics, intensity and dropout differ from any particular real storm. Results on "
        "this variant are evidence of robustness to the modelled effects only.\n- Particle "
        "returns are labelled with one class; the source taxonomy may not have a weather class, "
        "so that label is shared with other noise.",
        "compare": "compare against real adverse-weather data where possible.",
    },
    "sensor": {
        "word": "sensor",
        "direct_use": "Training and evaluating LiDAR perception across sensors: train on "
        "{src} as the target sensor would have scanned it, test on real scans of that sensor, or "
        "measure how a model trained on {src} degrades on another sensor's geometry.",
        "out_of_scope": "Claims about the target sensor's real behaviour without checking "
        "against its own recordings: its scans here are ray-cast against a surfel model of the "
        "source's scenes (see Physical model and limitations).",
        "rationale": "A labelled dataset exists for few sensors. This variant scans every scene "
        "of {src} again with another sensor's beams from the same poses, one output scan per "
        "source scan, so that labels, poses and calibration carry over.",
        "annotations": "Every point is a new beam of the target sensor; its label is the label "
        "of the source surface it hit (provenance.zarr names the source return, in the scan of "
        "the frame's window it came from).",
        "risks": "- The scene model is the surfels of a window of source scans: surfaces no scan "
        "of the window saw are empty, and rings beyond the source's vertical field of view have "
        "little to hit.\n- Intensity is the surface's albedo seen at the target's incidence, in "
        "the target's encoding; it inherits the source's calibration.",
        "compare": "compare against real scans of the target sensor where possible.",
    },
    "corruption": {
        "word": "sensor-fault",
        "direct_use": "Evaluating (or training) LiDAR perception for robustness to sensor faults "
        "and scan artefacts on {src}: each C- variant is one corruption at one severity of the "
        "robustness suite (`lads suite`), so a model's score can be reported per corruption and "
        "severity; motion-recorded distorts each sweep by the motion its own poses recorded.",
        "out_of_scope": "Claims about how often a real sensor fails this way: the fault is "
        "applied to every scan at a fixed severity (see Physical model and limitations).",
        "rationale": "Robustness benchmarks report scores under sensor faults that real "
        "recordings rarely contain. This variant applies one modelled fault to every scan of "
        "{src}, one output scan per source scan, so that labels, poses and calibration carry "
        "over.",
        "annotations": "Points keep their labels; points a fault removes take their labels "
        "with them (physical mode).",
        "risks": "- The fault is a model: real lasers fail intermittently and real sweeps are "
        "distorted by the speed the car actually drove, which a C- variant replaces with the "
        "preset's (motion-recorded takes it from the poses, held constant over each sweep).",
        "compare": "compare against real recordings with the same fault where any exist.",
    },
    "intensity": {
        "word": "intensity",
        "direct_use": "Training and evaluating LiDAR perception with the intensity another "
        "sensor (or model) would have recorded, on the geometry and labels of {src}.",
        "out_of_scope": "Claims that the predicted intensity is the target sensor's measured "
        "value: it is a learned prediction (see Physical model and limitations).",
        "rationale": "Intensity differs between sensors and datasets more than geometry does. "
        "This variant replaces every point's intensity by a learned prediction from range, "
        "incidence and material, one output scan per source scan.",
        "annotations": "Geometry, point order and labels are the source's, unchanged.",
        "risks": "- The intensity generator was trained on few real frames; its error on scenes "
        "unlike them is larger than its test error.",
        "compare": "compare against real scans of the target sensor where possible.",
    },
}


# What the card's "Not modelled" list says for kinds other than weather (whose list is
# lads.card.sections.NOT_MODELLED).
NOT_MODELLED_BY_KIND: dict[str, tuple[str, ...]] = {
    "sensor": (
        "one return per beam: the nearest surface the beam meets, no dual returns",
        "no motion during a sweep: each scan is cast from one pose (no rolling shutter)",
        "no learned ray drop: a beam returns nothing only where it meets no surfel, leaves the "
        "range limits or is too weak for the target's detector",
        "no surface beyond the window's surfels: no mesh or learned completion of unseen parts",
        "no effect on cameras or other sensors of the source dataset",
    ),
    "corruption": (
        "beam missing: whole lasers fail for a whole scan; no intermittent or partial failure",
        "motion distortion: constant speed and turn rate over a sweep, the scene itself static; "
        "no compensation by the sensor or the dataset is undone",
        "crosstalk: one interfering LiDAR per scan, at one distance and azimuth, not occluded "
        "from the targets; no second return beside the false one",
        "incomplete echo: diffuse darkening only, no specular glint of the clear coat",
        "no effect on cameras or other sensors of the source dataset",
    ),
    "intensity": (
        "geometry, dropout and labels are the source's: only intensity changes",
        "no effect on cameras or other sensors of the source dataset",
    ),
}


def variant_kind(stage_names: list[str]) -> str:
    """ "sensor" when a stage changes the sensor, "corruption" when one applies a sensor
    fault, "weather" when one adds weather, else "intensity" (a learned intensity only)."""
    if "sensor" in stage_names:
        return "sensor"
    if any(n in FAULT_STAGES for n in stage_names):
        return "corruption"
    if any(n in WEATHER_STAGES for n in stage_names) or not stage_names:
        return "weather"
    return "intensity"


def kind_fields(kind: str, source_pretty: str) -> dict[str, Any]:
    """The card placeholders that depend on the kind of variant."""
    text = _TEXT[kind]
    return {f"kind_{k}": v.format(src=source_pretty) for k, v in text.items()}
