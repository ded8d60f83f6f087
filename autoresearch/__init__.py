"""AutoResearch: an LLM research agent that drives any directory following the family contract."""

__version__ = "0.1.0"
