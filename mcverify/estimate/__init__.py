"""Rate estimation of a target event (collision, ellipse violation, ...) per cell: ``mcverify estimate``.

Above :mod:`mcverify.campaign`: an estimate is a campaign run whose episodes are chosen by the
estimator. :mod:`mcverify.estimate.mc` runs crude Monte Carlo with sequential stopping on an
anytime-valid interval (:mod:`mcverify.analysis.sequential`) through the ordinary runner, so
executors, chunk files, resume and reports are those of ``mcverify run``;
:mod:`mcverify.estimate.splitting` holds adaptive multilevel splitting for episode functions driven
by per-step noise.
"""
