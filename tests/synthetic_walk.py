"""The calibration random walk lives in benchmarks.walk (the rare-event benchmark uses it too)."""

from benchmarks.walk import Walk, WalkPath

__all__ = ["Walk", "WalkPath"]
