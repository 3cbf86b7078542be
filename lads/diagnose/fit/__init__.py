"""Fit: the design, the likelihood and its optimiser, fits in parallel, bootstrap weights."""
