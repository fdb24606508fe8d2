"""The installed gonio's version, recorded in run manifests, reports and exported materials."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version


def gonio_version() -> str:
    """The installed distribution's version string, or "unknown" when running from an uninstalled tree."""
    try:
        return version("gonio")
    except PackageNotFoundError:
        return "unknown"
