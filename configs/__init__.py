"""Default configuration files shipped with the station (robot models, setups, station config)."""

from pathlib import Path


def path(relative: str) -> Path:
    """Path of a shipped default, e.g. ``path("robots/hsr_jr680.toml")`` (the package's own folder:
    it is installed as files, and importlib.resources would cost every command's parser 4 ms)."""
    return Path(__file__).parent / relative
