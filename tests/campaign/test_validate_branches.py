"""noise.key_seed and the scheduled noise branches: validated with one line naming the field."""

from __future__ import annotations

import pytest

from mcverify.campaign.spec import campaign_from_dict
from mcverify.errors import CampaignError


@pytest.mark.parametrize(
    ("noise", "message"),
    [
        ({"key_seed": -2}, "noise.key_seed: must be -1 or an integer"),
        ({"key_seed": 2**31}, "noise.key_seed: must be -1 or an integer"),
        ({"key_seed": 1.5}, "expected an integer"),
        ({"branch_after_steps": [3], "branch_ids": []}, "noise.branch_ids: must have one id"),
        ({"branch_after_steps": [3, 3], "branch_ids": [1, 2]}, "noise.branch_after_steps: must be increasing"),
        ({"branch_after_steps": [2.5], "branch_ids": [1]}, "noise.branch_after_steps: must be increasing integer"),
        ({"branch_after_steps": [-1], "branch_ids": [1]}, "noise.branch_after_steps: must be increasing integer"),
        ({"branch_after_steps": [1], "branch_ids": [-3]}, "noise.branch_ids: must be integers"),
        ({"branch_after_steps": list(range(65)), "branch_ids": list(range(65))}, "at most 64 branches"),
    ],
)
def test_bad_noise_branches_are_one_line(noise, message):
    raw = {"campaign": {"name": "x", "seed": 1, "episodes": 1}, "model": {"noise": noise}}
    with pytest.raises(CampaignError) as err:
        campaign_from_dict(raw, source="f.toml")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_good_noise_branches_load():
    raw = {"campaign": {"name": "x", "seed": 1, "episodes": 1},
           "model": {"noise": {"key_seed": 7, "branch_after_steps": [3, 12], "branch_ids": [5, 9]}}}
    noise = campaign_from_dict(raw).cells[0].params.noise
    assert (noise.key_seed, noise.branch_after_steps, noise.branch_ids) == (7, (3.0, 12.0), (5.0, 9.0))
