"""Model validation for the campaign layer: :mod:`mcverify.model_validation` (next to the model) does the work;
the names here are those the campaign modules import."""

from __future__ import annotations

from mcverify.model_validation import short as _short
from mcverify.model_validation import validate_params

__all__ = ["_short", "validate_params"]
