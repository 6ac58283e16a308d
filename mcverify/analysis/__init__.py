"""The analysis layer: statistics of Monte-Carlo campaigns, computed from stored results only.

:mod:`~mcverify.analysis.stats` is the statistics API (rates with confidence intervals, comparisons
of cells, bootstrap intervals), implemented in :mod:`~mcverify.analysis.intervals`,
:mod:`~mcverify.analysis.comparisons` and :mod:`~mcverify.analysis.bootstrap`;
:mod:`~mcverify.analysis.summary` turns a run's episode rows into its per-cell summary.
"""
