"""Expected source inventories (YAML): a data package, read through lads.resources."""
