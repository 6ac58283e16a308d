"""The falsification layer: ``mcverify falsify``, a robustness-guided search for counterexamples.

:mod:`~mcverify.falsify.methods` holds the search methods (CMA-ES, cross-entropy, uniform random)
behind one ask/tell interface; :mod:`~mcverify.falsify.search` runs each generation as an ordinary
run folder through the campaign layer's executors and chunk store (resumable, deterministic for a
seed); :mod:`~mcverify.falsify.report` writes the search's report (its benchmark is
``python -m benchmarks.falsify``).
"""
