"""AutoResearch: an LLM research agent that drives any directory following the family contract."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cwh-autoresearch")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
