"""The benchmark layer: measurements run as commands, not as timed tests.

``mcverify bench`` (:mod:`~mcverify.bench.engine`) runs the engine against the naive reference loop
(:mod:`~mcverify.bench.naive`); ``mcverify bench-solver`` (:mod:`~mcverify.bench.solver_bench`,
rendered by :mod:`~mcverify.bench.solver_bench_report`) runs the solver backends against IPOPT.
Both check that the compared runs agree episode by episode (:mod:`~mcverify.bench.agreement`) and
record their figures in ``results/BENCHMARKS.md``.
"""
