"""Property-based tests of the campaign loader: generated valid specs load; mutated ones (a dropped
or renamed key, a wrong type, an impossible number, broken TOML text) either load or raise a
:class:`CampaignError` whose message is one line naming the offending field; never anything else.
"""

from __future__ import annotations

import json
import math
import os
import string
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from mcverify.campaign.spec import Campaign, CampaignError, campaign_from_dict, load_campaign

#: Examples per property; raise it for a longer hunt, e.g. MCVERIFY_FUZZ_EXAMPLES=5000.
FUZZ = settings(
    max_examples=int(os.environ.get("MCVERIFY_FUZZ_EXAMPLES", "150")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)

finite = dict(allow_nan=False, allow_infinity=False)

#: Model overrides the generator may set, each with values that are valid on their own and together.
MODEL_FIELDS: dict[str, st.SearchStrategy] = {
    "barrier.epsilon": st.floats(0.0, 1.0, **finite),
    "barrier.lambdas_m": st.lists(st.floats(0.1, 2.0, **finite), min_size=1, max_size=3),
    "noise.kind": st.sampled_from(["paper", "none"]),
    "noise.scale": st.floats(0.0, 3.0, **finite),
    "sim.max_time_s": st.floats(1.0, 30.0, **finite),
    "sim.substeps": st.integers(1, 40),
    "sim.control_period_s": st.floats(0.01, 0.2, **finite),
    "mpc.horizon": st.integers(2, 80),
    "mpc.max_iter": st.integers(1, 500),
    "scenario.front_speed_kmh": st.floats(0.0, 60.0, **finite),
    "scenario.ego_speed_mps": st.floats(0.0, 19.4, **finite),
    "scenario.front_accel_range_mps2": st.tuples(st.floats(0.0, 3.0, **finite), st.floats(0.1, 4.0, **finite)).map(
        lambda t: [t[0], t[0] + t[1]]
    ),
}
GRID_FIELDS = ("barrier.epsilon", "noise.scale", "scenario.front_speed_kmh", "sim.substeps")

names = st.text(string.ascii_letters + string.digits + "_- ", min_size=1, max_size=12).filter(str.strip)


@st.composite
def valid_specs(draw) -> dict[str, Any]:
    head: dict[str, Any] = {"name": draw(names), "episodes": draw(st.integers(1, 50))}
    if draw(st.booleans()):
        head["seed"] = draw(st.integers(0, 2**40))
    if draw(st.booleans()):
        head["description"] = draw(st.text(max_size=20))
    if draw(st.booleans()):
        head["common_random_numbers"] = draw(st.booleans())
    spec: dict[str, Any] = {"campaign": head}
    model: dict[str, dict[str, Any]] = {}
    for key in draw(st.lists(st.sampled_from(sorted(MODEL_FIELDS)), max_size=4, unique=True)):
        section, name = key.split(".")
        model.setdefault(section, {})[name] = draw(MODEL_FIELDS[key])
    if model:
        spec["model"] = model
    grid = {}
    for key in draw(st.lists(st.sampled_from(GRID_FIELDS), max_size=2, unique=True)):
        grid[key] = draw(st.lists(MODEL_FIELDS[key], min_size=1, max_size=3, unique=True))
    if grid:
        spec["grid"] = grid
    if draw(st.booleans()):
        bundles = {"A": {"mpc.phi_s": draw(st.floats(0.0, 3.0, **finite))},
                   "B": {"mpc.phi_s": 1.0, "episodes": draw(st.integers(1, 9))}}
        spec["axes"] = {"method": bundles}
    return spec


def paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key (and list index) of a spec, as a path from the top."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            out.append((*prefix, k))
            out += paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.append((*prefix, i))
            out += paths(v, (*prefix, i))
    return out


def get_parent(spec: dict, path: tuple):
    node = spec
    for k in path[:-1]:
        node = node[k]
    return node


def leaf_name(path: tuple) -> str:
    """The name a message must mention: the last key of the path (a dotted key's last part)."""
    key = [k for k in path if isinstance(k, str)][-1]
    return key


def load(spec: dict) -> Campaign | CampaignError:
    try:
        return campaign_from_dict(spec, source="fuzz.toml")
    except CampaignError as err:
        message = str(err)
        assert message and "\n" not in message, repr(message)
        assert message.startswith("fuzz.toml"), message
        assert len(message) < 400, message
        return err


def names_field(err: CampaignError, *keys: str) -> bool:
    text = str(err)
    return any(k in text or k.replace("_kmh", "_mps") in text for k in keys)


@FUZZ
@given(valid_specs())
def test_generated_specs_load(spec):
    camp = load(spec)
    assert isinstance(camp, Campaign), str(camp)
    n_cells = math.prod(len(v) for v in spec.get("grid", {}).values()) * (2 if "axes" in spec else 1)
    assert len(camp.cells) == n_cells
    assert camp.total_episodes == sum(c.episodes for c in camp.cells)


@FUZZ
@given(valid_specs(), st.data())
def test_a_dropped_key_loads_or_names_it(spec, data):
    path = data.draw(st.sampled_from([p for p in paths(spec) if isinstance(p[-1], str)]))
    del get_parent(spec, path)[path[-1]]
    result = load(spec)
    if isinstance(result, CampaignError):
        # only required keys may be missed: the campaign table, its name and episode count,
        # and a grid value list emptied of all its values
        assert names_field(result, leaf_name(path), "[campaign]", "name", "episodes"), (path, str(result))


@FUZZ
@given(valid_specs(), st.data(), st.text(string.ascii_lowercase + "_", min_size=1, max_size=3))
def test_a_renamed_key_is_named_with_a_suggestion(spec, data, typo):
    path = data.draw(st.sampled_from([p for p in paths(spec) if isinstance(p[-1], str)]))
    assume(path[0] != "axes" or len(path) != 3)  # bundle labels are free names
    assume(path[0] != "reference")
    parent = get_parent(spec, path)
    new = path[-1] + typo
    parent[new] = parent.pop(path[-1])
    result = load(spec)
    if path[:1] == ("axes",) and len(path) == 2:  # axis names are free as well
        return
    assert isinstance(result, CampaignError), (path, new)
    assert new in str(result) or new.split(".")[-1] in str(result), (path, str(result))


other_types = st.one_of(
    st.text(max_size=5), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=False),
    st.lists(st.text(max_size=3), max_size=2), st.just({"x": 1}), st.just([]), st.just({}),
)


@FUZZ
@given(valid_specs(), st.data(), other_types)
def test_a_wrong_type_is_refused_naming_the_field(spec, data, value):
    path = data.draw(st.sampled_from(paths(spec)))
    parent = get_parent(spec, path)
    old = parent[path[-1]]
    assume(type(value) is not type(old) and not (isinstance(old, float) and type(value) is int))
    assume(not (path[-1] == "description" and isinstance(value, str)))
    parent[path[-1]] = value
    result = load(spec)
    if isinstance(result, CampaignError):
        assert names_field(result, leaf_name(path)), (path, value, str(result))


impossible = st.sampled_from([-1, 0, -1e-9, 1e300, -1e300, math.nan, math.inf, -math.inf, 2**63 - 1, 10**12])


@FUZZ
@given(valid_specs(), st.data(), impossible)
def test_an_impossible_number_is_refused_naming_the_field(spec, data, value):
    numeric = [p for p in paths(spec) if isinstance(get_parent(spec, p)[p[-1]], int | float)
               and not isinstance(get_parent(spec, p)[p[-1]], bool)]
    assume(numeric)
    path = data.draw(st.sampled_from(numeric))
    get_parent(spec, path)[path[-1]] = value
    result = load(spec)
    if isinstance(result, CampaignError):
        assert names_field(result, leaf_name(path)), (path, value, str(result))


@pytest.mark.parametrize("key, value, fragment", [
    (("campaign", "episodes"), -3, "episodes: must be >= 1"),
    (("campaign", "episodes"), 10**12, "episodes"),
    (("campaign", "seed"), -1, "seed: must be >= 0"),
    (("model", "barrier", "epsilon"), -0.1, "barrier.epsilon: must be >= 0"),
    (("model", "scenario", "ego_speed_mps"), 25.0, "ego_speed_mps"),
    (("model", "scenario", "front_accel_range_mps2"), [3.0, 3.0], "front_accel_range_mps2"),
    (("grid", "noise.scale"), [], "non-empty list"),
])
def test_named_impossible_values(key, value, fragment):
    spec: dict[str, Any] = {"campaign": {"name": "x", "episodes": 2}}
    node = spec
    for k in key[:-1]:
        node = node.setdefault(k, {})
    node[key[-1]] = value
    result = load(spec)
    assert isinstance(result, CampaignError) and fragment in str(result), str(result)


def toml_text(spec: dict) -> str:
    """A TOML document for the generated specs (tables of scalars, lists and sub-tables)."""
    lines: list[str] = []

    def scalar(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):  # a TOML basic string: control characters and DEL escaped
            body = "".join(
                f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7F or c in '"\\' else c for c in v
            )
            return f'"{body}"'
        if isinstance(v, list):
            return "[" + ", ".join(scalar(x) for x in v) + "]"
        return repr(v)

    def table(name: str, node: dict):
        simple = {k: v for k, v in node.items() if not isinstance(v, dict)}
        nested = {k: v for k, v in node.items() if isinstance(v, dict)}
        if simple or not nested:
            lines.append(f"[{name}]")
            lines.extend(f"{json.dumps(k)} = {scalar(v)}" for k, v in simple.items())
        for k, v in nested.items():
            table(f"{name}.{json.dumps(k)}", v)

    for name, node in spec.items():
        table(json.dumps(name), node)
    return "\n".join(lines) + "\n"


@FUZZ
@given(valid_specs(), st.data())
def test_broken_toml_text_is_one_line(tmp_path_factory, spec, data):
    text = toml_text(spec)
    path = Path(tmp_path_factory.mktemp("toml")) / "c.toml"
    path.write_text(text)
    assert isinstance(load_campaign(path), Campaign), text  # the writer itself is right
    where = data.draw(st.integers(0, len(text) - 1))
    how = data.draw(st.sampled_from(["delete", "insert", "truncate"]))
    if how == "delete":
        broken = text[:where] + text[where + 1:]
    elif how == "insert":
        broken = text[:where] + data.draw(st.sampled_from(list("[]\"'=.,{}#\n\\x") + ["\x00", "é"])) + text[where:]
    else:
        broken = text[:where]
    path.write_text(broken)
    try:
        load_campaign(path)
    except CampaignError as err:
        message = str(err)
        assert "\n" not in message and message.startswith(str(path)), message
        if "malformed TOML" not in message:  # well-formed but now invalid: named like the others
            assert ":" in message


def test_binary_and_unreadable_files(tmp_path):
    bad = tmp_path / "bin.toml"
    bad.write_bytes(b"\xff\xfe\x00[campaign]")
    with pytest.raises(CampaignError, match="not a text file"):
        load_campaign(bad)
    with pytest.raises(CampaignError, match="is a folder"):
        load_campaign(tmp_path)

