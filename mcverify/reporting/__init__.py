"""The report layer: tables, figures and pages regenerated from a run's stored data only.

:mod:`~mcverify.reporting.run_report` writes ``mcverify report RUN_DIR`` (Markdown, with
:mod:`~mcverify.reporting.html` for the self-contained page) from :mod:`~mcverify.reporting.tables` and
:mod:`~mcverify.reporting.paper_tables` (the paper's Tables II-IV beside the run's numbers) and the
figures chosen by :mod:`~mcverify.reporting.run_figures`: campaign-level ones in
:mod:`~mcverify.reporting.cell_figures`, one-episode ones in :mod:`~mcverify.reporting.episode_figures`,
both on :mod:`~mcverify.reporting.figure_common`. :mod:`~mcverify.reporting.compare` compares two runs;
:mod:`~mcverify.reporting.episode_plot` is the figure ``mcverify replay`` writes. Same data, same bytes.
"""
