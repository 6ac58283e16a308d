"""The report layer: tables, figures and pages regenerated from a run's stored data only.

:mod:`~mcverify.report.run_report` writes ``mcverify report RUN_DIR`` (Markdown, with
:mod:`~mcverify.report.html` for the self-contained page) from :mod:`~mcverify.report.tables` and
:mod:`~mcverify.report.paper_tables` (the paper's Tables II-IV beside the run's numbers) and the
figures chosen by :mod:`~mcverify.report.run_figures`: campaign-level ones in
:mod:`~mcverify.report.cell_figures`, one-episode ones in :mod:`~mcverify.report.episode_figures`,
both on :mod:`~mcverify.report.figure_common`. :mod:`~mcverify.report.compare` compares two runs;
:mod:`~mcverify.report.episode_plot` is the figure ``mcverify replay`` writes. Same data, same bytes.
"""
