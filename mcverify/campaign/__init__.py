"""The campaign layer: from a campaign file to a finished run folder.

* :mod:`~mcverify.campaign.spec`: campaign files (TOML), validated at load, expanded into cells;
* :mod:`~mcverify.campaign.overrides` / :mod:`~mcverify.campaign.grid`: the settable model fields and their
  typed overrides; the grid and axes of a campaign file and the cells they expand into;
* :mod:`~mcverify.campaign.work`: the unit a worker runs (cell-local episode ids of one cell) and its outcome;
* :mod:`~mcverify.campaign.scheduler`: chunks, retries, the executor interface, the serial executor;
* :mod:`~mcverify.campaign.local` / :mod:`~mcverify.campaign.ray_executor`: worker processes, Ray tasks;
* :mod:`~mcverify.campaign.executors`: the executors' face (``make_executor``);
* :mod:`~mcverify.campaign.runner`: run and resume into a run folder (manifest, chunks, report);
* :mod:`~mcverify.campaign.replay`: re-simulate one stored episode and check it bit for bit.

(Named ``campaign`` rather than ``run`` because :func:`mcverify.run` is a function of the public API.)
"""
