"""Shared test fixtures and helpers.

Importing :mod:`mcverify.sim` here puts JAX's 64-bit mode and the XLA ISA cap in place before any
test module computes, whatever order pytest collects the modules in.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import mcverify.sim  # noqa: F401 - float64 and the XLA ISA cap before any JAX computation

TESTS_DIR = Path(__file__).resolve().parent
REPO_ROOT = TESTS_DIR.parent
FIXTURES_DIR = TESTS_DIR / "fixtures"


def fma_disabled() -> bool:
    """XLA CPU contracts a*b+c into FMAs differently for a batch and for one episode unless the
    ISA is capped below FMA3 (XLA_FLAGS=--xla_cpu_max_isa=AVX); only then are bits comparable."""
    match = re.search(r"--xla_cpu_max_isa=(\w+)", os.environ.get("XLA_FLAGS", ""))
    return bool(match) and match.group(1).upper() in {"SSE4_2", "AVX"}


def _assert_batch_equals_loop(batched: np.ndarray, looped: np.ndarray) -> None:
    if fma_disabled():
        np.testing.assert_array_equal(batched, looped)
    else:  # last-bit differences from FMA contraction only
        np.testing.assert_allclose(batched, looped, rtol=1e-12, atol=1e-12)


@pytest.fixture
def assert_batch_equals_loop() -> Callable[[np.ndarray, np.ndarray], None]:
    """``check(batched, looped)``: a vmapped batch equals the one-at-a-time loop, bit for bit
    when FMA contraction is off (the package's default), else to 1e-12."""
    return _assert_batch_equals_loop


@pytest.fixture
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture
def tiny_campaign_path() -> Path:
    """A two-cell campaign of short real closed-loop episodes (``tests/fixtures/tiny.toml``)."""
    return FIXTURES_DIR / "tiny.toml"
