"""The installed vibroplan version, as plan.json, output markers and ``--version`` give it."""

from __future__ import annotations


def version_string() -> str:
    """The installed vibroplan version (``0+unknown`` when run from an uninstalled tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vibroplan")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"
