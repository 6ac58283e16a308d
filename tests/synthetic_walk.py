"""The calibration random walk lives in mcverify.estimate.synthetic (the benchmark uses it too)."""

from mcverify.estimate.synthetic import Walk, WalkPath

__all__ = ["Walk", "WalkPath"]
