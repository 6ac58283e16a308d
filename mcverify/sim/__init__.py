"""The simulated world in JAX: vehicles, geometry, perception noise, barriers, agents and the plant.

This is the only layer that configures JAX, and it does so on import, because reproducibility rests
on two process-wide settings that must be in place before JAX's backend starts:

* 64-bit floats: the plant, the checks and the CasADi solver must agree to the last bit for
  ``mcverify replay`` to reproduce stored metrics exactly;
* ``--xla_cpu_max_isa=AVX`` in ``XLA_FLAGS`` (unless the caller already chose an ISA): on CPUs with
  FMA3, XLA contracts ``a*b + c`` into fused multiply-adds differently for a vmapped batch and for
  a single episode, so the same episode would differ in its last bits between a chunk of 8 and a
  replay of 1 (and the closed loop amplifies last bits into different solver iterates).

Importing :mod:`mcverify` alone (statistics, reports, reading runs) changes neither.
"""

import os

_ISA_FLAG = "--xla_cpu_max_isa=AVX"
if "xla_cpu_max_isa" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_ISA_FLAG}".strip()

import jax  # noqa: E402 - after XLA_FLAGS, on purpose

jax.config.update("jax_enable_x64", True)
