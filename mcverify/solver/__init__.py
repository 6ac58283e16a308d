"""The solver layer: the TO-CBF-MPC NLP solved on the host, from compiled C.

* :mod:`~mcverify.solver.kernels`: the NLP's functions generated as C by CasADi and compiled once
  per structure (hash-keyed disk cache); the shipped C of ``csrc`` compiled the same way.
* :mod:`~mcverify.solver.cfun`: ctypes binding of one generated function (numpy buffers).
* :mod:`~mcverify.solver.kkt`: the banded KKT structure of a kernel, read from its sparsity.
* :mod:`~mcverify.solver.ipm` with ``csrc/ipm.c``, ``csrc/ipm.h``: the C interior-point method and
  its ctypes binding (ABI checked at load).
* :mod:`~mcverify.solver.backends`: IPOPT (the reference) and the IPM with IPOPT as fallback, one
  per name of :data:`mcverify.model.BACKEND_NAMES`.
* :mod:`~mcverify.solver.mpc`: :class:`~mcverify.solver.mpc.MpcSolver`, a plan from a measured state.
"""
