"""The dataset-card template: a data package, read through lads.resources."""
