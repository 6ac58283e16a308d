"""Between a falsification search's loop and its method: the cube it searches, what it asks, what it is told.

The method searches the unit cube of the ``[falsify.bounds]`` fields followed by the adversary's theta
(:func:`search_dimension`); each point it asks becomes a :class:`~mcverify.falsify.splitting.Candidate`
(:func:`ask`), with its perception-error schedule when the table has ``[falsify.adversary]``
(:func:`schedules`) and, for a ``common_noise`` search, the one noise seed of every candidate
(:func:`noise_seed`). :func:`tell` gives the method its candidates' values back: the robustness (or
guide) per candidate, or for splitting the running values per control step.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from mcverify.campaign.search_space import SearchSpace
from mcverify.campaign.spec import Campaign
from mcverify.falsify import candidate_scores, methods
from mcverify.falsify.parametrisations import Parametrisation, parametrisation, theta_of_unit
from mcverify.falsify.splitting import Candidate, NoiseSplitting
from mcverify.sim.schedule import ErrorInput


def adversary_of(campaign: Campaign, space: SearchSpace) -> Parametrisation | None:
    """The parametrisation of the searched perception error (``[falsify.adversary]``), None without one."""
    return None if space.adversary is None else parametrisation(space.adversary, campaign.cells[0].params.sim)


def search_dimension(campaign: Campaign, space: SearchSpace) -> int:
    """Coordinates of the unit cube searched: the ``[falsify.bounds]`` fields, then the adversary's theta."""
    adversary = adversary_of(campaign, space)
    return space.dimension + (0 if adversary is None else adversary.dimension)


def schedules(adversary: Parametrisation | None, space: SearchSpace, campaign: Campaign,
              candidates: list[Candidate]) -> dict[int, ErrorInput] | None:
    """Each candidate cell's error schedule by global episode id (cell k is candidate k), None without an
    adversary."""
    if adversary is None:
        return None
    return {cell.episode_offset: adversary.schedule(theta_of_unit(c.point[space.dimension:]))
            for cell, c in zip(campaign.cells, candidates, strict=False)}


def noise_seed(campaign_seed: int, search_seed: int) -> int:
    """``noise.key_seed`` of every candidate of a ``common_noise`` search: one noise realisation per
    (campaign seed, search seed), so independent trials see independent noise."""
    digest = hashlib.sha256(f"common-noise:{campaign_seed}:{search_seed}".encode()).digest()
    return int.from_bytes(digest[:8], "big") % 2**31


def ask(search: methods.Searcher | NoiseSplitting, common_seed: int = -1) -> list[Candidate]:
    """The method's next candidates (a scenario-space method's points carry ``common_seed``)."""
    if isinstance(search, NoiseSplitting):
        return search.ask()
    return [Candidate(tuple(float(x) for x in p), common_seed) for p in search.ask()]


def tell(search: methods.Searcher | NoiseSplitting, candidates: list[Candidate], robs: np.ndarray, gen_dir: Path,
         rows: list[dict[str, Any]], steered_by: str, periods_s: list[float]) -> None:
    """Tell the method its candidates' values ``robs``; splitting is told the running values of
    ``steered_by`` (the requirement, or its ``@run`` guide) per control step instead."""
    if not isinstance(search, NoiseSplitting):
        search.tell(np.array([c.point for c in candidates]), robs)
        return
    search.tell(candidates, [candidate_scores.running_robustness(gen_dir, row, steered_by, dt)
                             for row, dt in zip(rows, periods_s, strict=True)])
