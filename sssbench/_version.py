"""The package version (one place: the root package and file headers read it)."""

__version__ = "0.1.0"
