"""The simulated world in JAX: vehicles, geometry, perception noise, barriers, agents and the plant.

This is the only layer that configures JAX, and it does so on import, because reproducibility rests
on two process-wide settings that must be in place before JAX's backend starts:

* 64-bit floats: the plant, the checks and the CasADi solver must agree to the last bit for
  ``mcverify replay`` to reproduce stored metrics exactly;
* XLA's CPU options pinned in ``XLA_FLAGS`` (:func:`mcverify.provenance.pin_xla_flags`, replacing
  any ``--xla_cpu_*`` flag of the caller's): ``--xla_cpu_max_isa=AVX``, since on CPUs with FMA3 XLA
  contracts ``a*b + c`` into fused multiply-adds differently for a vmapped batch and for a single
  episode (and the closed loop amplifies last bits into different solver iterates).

Importing :mod:`mcverify` alone (statistics, reports, reading runs) changes neither.
"""

from mcverify import provenance

provenance.pin_xla_flags()

import jax  # noqa: E402 - after XLA_FLAGS, on purpose

jax.config.update("jax_enable_x64", True)
