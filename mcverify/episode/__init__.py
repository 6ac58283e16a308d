"""The episode layer: the closed loop of a chunk of disturbed episodes.

* :mod:`~mcverify.episode.rollout`: the plant in JAX (observe and advance, vmapped over the chunk,
  ``lax.scan`` over sub-steps) around the host planner, step by step until every episode ends;
* :mod:`~mcverify.episode.row`: an episode's row (:data:`mcverify.schema.EPISODE_COLUMNS`) and error rows;
* :mod:`~mcverify.episode.recording`: the typed full-resolution recording of an episode.
"""
