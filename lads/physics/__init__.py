"""Pure physics: no file I/O. Weather, Mie, size distributions and per-point modalities."""
