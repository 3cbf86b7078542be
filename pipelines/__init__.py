"""Shipped build pipelines (YAML): a data package, read through lads.resources."""
