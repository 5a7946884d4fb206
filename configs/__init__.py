"""Default configuration files shipped with the station (robot models, setups, station config)."""

from importlib.resources import files
from pathlib import Path


def path(relative: str) -> Path:
    """Path of a shipped default, e.g. ``path("robots/hsr_jr680.toml")``."""
    return Path(str(files(__name__).joinpath(relative)))
