"""The maintained benchmarks: measurements run as commands (``python -m benchmarks.NAME``), not as
timed tests, and not part of the installed library.

Each writes only its own generated section of ``results/BENCHMARKS.md`` (:mod:`benchmarks.section`):

- :mod:`benchmarks.engine`: the engine against the compiled IPOPT loop (and the naive loop);
- :mod:`benchmarks.solver`: the solver backends against each other;
- :mod:`benchmarks.falsify`: success rate and episodes to the first counterexample per search method;
- :mod:`benchmarks.rare`: splitting against crude Monte Carlo on the calibration walk;
- :mod:`benchmarks.plant`: the JAX side alone per batch size, on CPU and GPU;
- :mod:`benchmarks.validation`: the rare-event estimators against a crude Monte Carlo reference;
- :mod:`benchmarks.worker_scaling`: episodes per wall-minute against the number of worker processes;
- :mod:`benchmarks.surrogate_coverage`: the rare-event estimators' coverage on a surrogate with exact p;
- :mod:`benchmarks.worst_case`: the lowest robustness (or first counterexample) per search method against ε.
"""
