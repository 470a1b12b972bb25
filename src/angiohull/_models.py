"""Small helpers for the pydantic schemas of angiohull's files (``study.yaml``, experiment
configurations): which model a field holds, and short reprs for error messages."""

from __future__ import annotations

from typing import Any, Optional, get_args

from pydantic import BaseModel

__all__ = ["find_model", "short_repr"]


def find_model(annotation: Any) -> Optional[type[BaseModel]]:
    """The pydantic model inside a field's annotation (``Optional[M]``, ``list[M]``, ``M``), or None."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for argument in get_args(annotation):
        found = find_model(argument)
        if found is not None:
            return found
    return None


def short_repr(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters with an ellipsis."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
