"""Where lads' shipped data lives: one name per resource, read through importlib.resources.

Everything the code reads at run time ships inside the `lads` package: sensor profiles
(`lads/sensors/*.yaml`), materials (`lads/physics/materials.yaml`), intensity weights and
model cards (`lads/intensity/weights/`), and the top-level folders of the repository
`pipelines/`, `manifests/` and `dataset_cards/`, which setuptools maps to the packages
`lads.pipelines`, `lads.manifests` and `lads.dataset_cards` (pyproject.toml, package-dir).
So the same names work from a checkout installed editable and from the wheel; no code looks
for the repository root.

lads is always installed as plain files (a wheel, never a zip), so each resource folder is
handed out as a `pathlib.Path`.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from lads.errors import ConfigError

PIPELINES = "lads.pipelines"
TRAIN_CONFIGS = "lads.pipelines.train"
MANIFESTS = "lads.manifests"
DATASET_CARDS = "lads.dataset_cards"
SENSORS = "lads.sensors"
INTENSITY = "lads.intensity"

CARD_TEMPLATE = "template.md"
WEIGHTS_FOLDER = "weights"


def resource_dir(package: str) -> Path:
    """The folder of the resource package `package` (one of the names above).

    Raises:
        ConfigError: the package is missing or not installed as files (a broken install).
    """
    try:
        root = importlib.resources.files(package)
    except ModuleNotFoundError as exc:
        raise ConfigError(
            f"lads resource package {package!r} is missing ({exc}); the installation is "
            "incomplete: reinstall lads (pip install --force-reinstall lads)."
        ) from None
    path = Path(str(root))
    if not path.is_dir():
        raise ConfigError(
            f"lads resource package {package!r} is not a folder on disk ({root}); install lads "
            "from its wheel or a checkout, not as a zip."
        )
    return path


def pipelines_dir() -> Path:
    """Shipped build pipelines, `<variant>.yaml` and `<source>-<variant>.yaml`."""
    return resource_dir(PIPELINES)


def train_configs_dir() -> Path:
    """Shipped training configs of the intensity models, `<name>.yaml`."""
    return resource_dir(TRAIN_CONFIGS)


def manifests_dir() -> Path:
    """Expected source inventories, `<dataset>.yaml`."""
    return resource_dir(MANIFESTS)


def card_template() -> Path:
    """The dataset-card body template."""
    return resource_dir(DATASET_CARDS) / CARD_TEMPLATE


def sensors_dir() -> Path:
    """Shipped sensor profiles, `<name>.yaml`."""
    return resource_dir(SENSORS)


def weights_dir() -> Path:
    """Shipped intensity weights (`<name>.pt`) and their model cards (`<name>.md`)."""
    return resource_dir(INTENSITY) / WEIGHTS_FOLDER
