"""mcverify: Monte-Carlo verification and falsification of VL-CBF / TO-CBF-MPC overtaking controllers.

Importing the package switches JAX to 64-bit floats: the plant, the checks and the CasADi solver
must agree to the last bit for ``mcverify replay`` to reproduce stored metrics exactly.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
