"""The engine's input error: a ``ValueError`` that names the offending field."""

from __future__ import annotations


class ParameterError(ValueError):
    """Invalid input. ``field`` is a dotted path in the engine's own names (for example
    ``links[2].inertia`` or ``dt``); ``reason`` says what is wrong."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason
