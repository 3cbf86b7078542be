"""Training batches drawn from the range-image cache of a `lads train` run: random azimuth
crops of cached frames for the convolutional terms, and random labelled points from all of a
pair's target frames for the pointwise identity term. Seeded by the run's generator only."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import torch

from lads.errors import TrainingError
from lads.intensity.cache import CachedFrame, CacheJob, read_frame
from lads.intensity.features import channel_names

FRAME_CACHE = 64  # frames kept in memory; the rest are read from zarr when sampled


@dataclass
class Batch:
    raw: torch.Tensor  # (B, C, H, W) raw channels
    mask: torch.Tensor  # (B, 1, H, W)
    z: torch.Tensor | None  # (B, 1, H, W) target intensity in the pair's z-space
    labelled: bool
    extinction: torch.Tensor  # (B,) 1/m
    classes: torch.Tensor | None = None  # (B, 1, H, W) int32 class id per pixel, -1 none


class Sampler:
    """Random circular azimuth crops of cached frames, seeded; frames read lazily.

    At most FRAME_CACHE frames stay in memory, the least recently sampled evicted first.
    Which frames are held never changes what is sampled: the draws come from `rng` only.
    """

    def __init__(self, run_dir: Path, jobs: list[CacheJob], rng: np.random.Generator) -> None:
        self.run_dir = run_dir
        self.rng = rng
        self.by_domain: dict[tuple[str, str], list[CacheJob]] = {}
        for job in jobs:
            self.by_domain.setdefault((job.pair, job.role), []).append(job)
        self._frames: OrderedDict[str, CachedFrame] = OrderedDict()
        self._occupied_pixels: dict[str, npt.NDArray[np.int64]] = {}

    def frame(self, job: CacheJob) -> CachedFrame:
        """The cached frame of `job`, read from zarr unless held (least recently used
        first out, so frames drawn often stay while rarely drawn ones are dropped)."""
        cached = self._frames.get(job.node)
        if cached is not None:
            self._frames.move_to_end(job.node)
            return cached
        if len(self._frames) >= FRAME_CACHE:
            self._frames.popitem(last=False)
        cached = self._frames[job.node] = read_frame(self.run_dir, job)
        return cached

    def batch(
        self, pair: str, role: str, size: int, width: int, z_stats: tuple[float, float, float]
    ) -> Batch:
        jobs = self.by_domain[(pair, role)]
        raws, masks, zs, ext, classes = [], [], [], [], []
        labelled = True
        mean, std, floor = z_stats
        for _ in range(size):
            f = self.frame(jobs[int(self.rng.integers(len(jobs)))])
            w_full = f.inputs.shape[-1]
            cols = (int(self.rng.integers(w_full)) + np.arange(width)) % w_full
            raw = f.inputs[:, :, cols]
            raws.append(raw)
            classes.append(f.class_plane[None, :, cols])
            masks.append(raw[GEN_MASK_INDEX[raw.shape[0]]][None])
            if f.target is not None and role == "target":
                zs.append(((np.log(f.target[:, cols] + floor) - mean) / std)[None])
            labelled &= f.labelled
            ext.append(f.extinction_per_m)
        mask = torch.from_numpy(np.stack(masks))
        z = torch.from_numpy(np.stack(zs)).float() * mask if zs else None
        return Batch(
            torch.from_numpy(np.stack(raws)),
            mask,
            z,
            labelled,
            torch.tensor(ext, dtype=torch.float32),
            torch.from_numpy(np.stack(classes)),
        )

    def points(self, pair: str, count: int, z_stats: tuple[float, float, float]) -> Batch:
        """`count` occupied target pixels drawn at random from all of the pair's target
        frames (frame, then pixel, uniformly), as a (1, C, count, 1) batch."""
        jobs = self.by_domain[(pair, "target")]
        mean, std, floor = z_stats
        which = self.rng.integers(len(jobs), size=count)
        raws, zs, ext, classes = [], [], [], []
        labelled = True
        for j in np.unique(which):
            f = self.frame(jobs[int(j)])
            if f.target is None:
                raise TrainingError(f"pair {pair}: target frame {f.frame} carries no intensity.")
            flat = f.inputs.reshape(f.inputs.shape[0], -1)
            occupied = self._occupied(jobs[int(j)].node, flat)
            pick = occupied[self.rng.integers(len(occupied), size=int(np.sum(which == j)))]
            raws.append(flat[:, pick])
            classes.append(f.class_plane.reshape(-1)[pick])
            zs.append((np.log(f.target.reshape(-1)[pick] + floor) - mean) / std)
            ext.append(np.full(len(pick), f.extinction_per_m))
            labelled &= f.labelled
        raw = torch.from_numpy(np.concatenate(raws, 1)[None, :, :, None])
        z = torch.from_numpy(np.concatenate(zs)[None, None, :, None]).float()
        extinction = np.concatenate(ext)
        if np.ptp(extinction) > 0:
            raise TrainingError(
                f"pair {pair}: target frames of different extinction; the "
                "pointwise identity batch needs one per pair."
            )
        return Batch(
            raw,
            torch.ones_like(z),
            z,
            labelled,
            torch.tensor(extinction[:1], dtype=torch.float32),
            torch.from_numpy(np.concatenate(classes)[None, None, :, None]),
        )

    def _occupied(self, node: str, flat: npt.NDArray[np.float32]) -> npt.NDArray[np.int64]:
        if node not in self._occupied_pixels:
            self._occupied_pixels[node] = np.flatnonzero(flat[GEN_MASK_INDEX[flat.shape[0]]] > 0)
        return self._occupied_pixels[node]


GEN_MASK_INDEX = {len(channel_names(s)): channel_names(s).index("mask") for s in (False, True)}
