"""Shipped training configs of the intensity models (YAML): a data package."""
