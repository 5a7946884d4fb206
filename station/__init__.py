"""The station: configuration, sessions, command line, live view."""

DISTRIBUTION = "calibration-station"  # pyproject.toml's [project] name


def installed_version() -> str:
    """The installed package's version (importlib.metadata, looked up only when asked)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return "unknown (not installed: pip install -e .)"
