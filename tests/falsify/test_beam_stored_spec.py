"""A beam's spec as folders store it, and the draws it keys: flat dicts written before ``BeamShape`` existed stay
readable and resumable, a campaign file's table gives the spec its folders hold, and the children's draws are the
ones the beam drew before (no simulation here)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from mcverify import store
from mcverify.campaign.spec import load_campaign
from mcverify.errors import RunError
from mcverify.falsify import beam
from mcverify.files import write_json_atomic

ROOT = Path(__file__).resolve().parents[2]
#: ``beam/restart-00/beam.json`` of a beam trial of ``campaigns/adversary_t1_beam.toml`` (benchmarks.falsify,
#: seed 0), written by the code before BeamShape: the flat format every stored beam folder holds.
STORED_T1 = {"first_step": 210, "last_step": 270, "segment_steps": 10, "branching": 8, "width": 8,
             "requirement": "theorem5_certified", "channels": ["front_x", "front_y", "front_v"], "units": "bang_bang",
             "score": "theorem5", "front_share": 1.0, "opp_share": 0.0, "seed": 0, "restart": 0, "format": 1}
SPEC = beam.BeamSpec(first_step=5, last_step=15, segment_steps=5, requirement="ellipse", seed=7,
                     shape=beam.BeamShape(branching=2, width=2, channels=("front_x", "front_y")))


def _flat(stored: dict) -> dict:
    return {k: v for k, v in stored.items() if k != "format"}


def test_an_old_flat_spec_reads_back_to_the_same_dict_in_the_same_order():
    spec = beam.BeamSpec.from_json(_flat(STORED_T1))
    assert spec.shape == beam.BeamShape(8, 8, ("front_x", "front_y", "front_v"), "bang_bang", "theorem5", 1.0, 0.0)
    assert (spec.first_step, spec.last_step, spec.segment_steps) == (210, 270, 10)
    assert spec.requirement == "theorem5_certified"
    assert list(spec.to_json().items()) == list(_flat(STORED_T1).items())


def test_the_campaign_table_gives_the_stored_spec():
    campaign = load_campaign(ROOT / "campaigns" / "adversary_t1_beam.toml")
    spec = beam.spec_of(campaign.falsify.beam, "theorem5_certified", 0, campaign.cells[0].params.sim)
    assert spec == beam.BeamSpec.from_json(_flat(STORED_T1))
    assert spec.shape is campaign.falsify.beam.shape  # one declaration, held by the table and the spec


def test_a_folder_written_before_is_accepted_and_another_spec_refused(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    write_json_atomic(old / "beam.json", STORED_T1)
    beam._check_config(old, beam.BeamSpec.from_json(_flat(STORED_T1)))  # what a resume checks: accepted
    with pytest.raises(RunError, match="another specification"):
        beam._check_config(old, beam.BeamSpec.from_json({**_flat(STORED_T1), "width": 4}))
    new = tmp_path / "new"
    new.mkdir()
    beam._check_config(new, SPEC)
    assert list(store.read_json(new / "beam.json").items()) == list({
        "first_step": 5, "last_step": 15, "segment_steps": 5, "branching": 2, "width": 2, "requirement": "ellipse",
        "channels": ["front_x", "front_y"], "units": "bang_bang", "score": "h_front", "front_share": 1.0,
        "opp_share": 1.0, "seed": 7, "restart": 0, "format": 1}.items())


@pytest.mark.parametrize(("depth", "rank", "digest"), [
    (0, 0, "42729374f622137bf9b07475275ae36ec804c1200ec4fb3300f66ea7559f5182"),
    (1, 1, "b26d4ad78cf6d3ef7eb69d50004706307b870ce59acb4c2855e61d713eb6e9b8"),
])
def test_children_draws_are_the_ones_drawn_before(depth, rank, digest):
    """The draws are keyed by (seed, restart, depth, rank, child); digests from the code before BeamShape."""
    node = beam.Node(np.zeros((30, 5)), 4, 0.0)
    kids = beam._children(SPEC, node, depth, rank, [0, 1])
    assert hashlib.sha256(np.stack(kids).tobytes()).hexdigest() == digest
