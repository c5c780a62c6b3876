"""Scenario families, net generation and the committed nets (sumo_nets/)."""

from __future__ import annotations

import dataclasses
import hashlib
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from priqn.errors import PriqnError
from priqn.paths import nets_dir
from priqn.sim import netgen, sumo
from priqn.sim.scenario import (
    KINDS,
    TrafficSpec,
    family_net_refs,
    hash_of_manifest,
    list_families,
    list_generated,
    load_family,
    load_manifest,
    manifest_hash,
    net_path,
)

TRAINING = ("tjunction", "fourway")
FAMILIES = ("tjunction", "fourway", "holdout", "out-of-range")


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


# --------------------------------------------------------------------------- SUMO


def test_sumo_binaries_and_version_found_without_sumo_home(monkeypatch):
    monkeypatch.delenv("SUMO_HOME", raising=False)
    assert Path(sumo.binary("netconvert")).is_file()
    assert Path(sumo.binary("sumo")).is_file()
    version = sumo.sumo_version()
    assert version.count(".") >= 1 and version.split(".")[0].isdigit()
    with pytest.raises(PriqnError, match="no SUMO program 'no-such-tool'") as exc:
        sumo.binary("no-such-tool")
    _one_line(exc)


def test_simulation_args_carry_measured_options(tmp_path):
    net = net_path("holdout/tjunction_00")
    args = sumo.simulation_args(net, seed=7, lateral_resolution_m=0.4)
    assert args[0] == sumo.binary("sumo")
    joined = " ".join(args)
    for opt in ("--step-length 0.1", "--seed 7", "--time-to-teleport -1", "--collision.action warn",
                "--collision.check-junctions true", "--lateral-resolution 0.4"):  # fmt: skip
        assert opt in joined
    with pytest.raises(PriqnError, match="no such net file"):
        sumo.simulation_args(tmp_path / "missing.net.xml", seed=0)


# --------------------------------------------------------------------------- families


def test_committed_families_load_and_have_the_paper_split():
    assert set(FAMILIES) <= set(list_families())
    for name in TRAINING:
        fam = load_family(name)
        assert fam.name == name and fam.kind == name and fam.n_nets >= 8
    hold = load_family("holdout")
    assert sorted(hold.kind) == ["fourway", "fourway", "tjunction"]
    seeds = [load_family(n).seed for n in FAMILIES]
    assert len(set(seeds)) == len(seeds), "each evaluation family must use its own seed stream"


def test_traffic_spec_fields_are_ranges():
    t = load_family("tjunction").traffic
    assert isinstance(t, TrafficSpec) and t.max_actors >= 1
    for name in ("vehicle_length_m", "vehicle_width_m", "speed_factor", "lateral_offset_m",
                 "obstacles_per_episode", "obstacle_length_m", "obstacle_width_m"):  # fmt: skip
        lo, hi = getattr(t, name)
        assert lo <= hi
    assert 10.0 <= t.lateral_offset_fade_m <= 30.0


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(text, encoding="utf-8")
    return p


GOOD = 'seed = 1\nn_nets = 2\nkind = "tjunction"\n'


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("seed = 1\nn_nets = [", r"fam\.toml: malformed TOML"),
        (GOOD + "colour = 1\n", r"fam\.toml: unknown key 'colour'"),
        (GOOD + "[traffic]\nmax_actor = 3\n", r"fam\.toml\.traffic: unknown key 'max_actor'"),
        (GOOD + "[geometry]\nlane_width_m = [3.6, 3.0]\n", r"geometry: lane_width_m: lower bound 3\.6 exceeds upper bound 3\.0"),
        (GOOD + "[geometry]\nlane_width_m = [3.0]\n", r"lane_width_m: expected a range \[lo, hi\] of 2 values"),
        (GOOD + "[geometry]\narm_length_m = [20.0, 50.0]\n", r"arm_length_m: expected values >= 60"),
        (GOOD + "[geometry]\narm_angle_jitter_deg = 30.0\n", r"arm_angle_jitter_deg: 30\.0 lets arms come 30 deg close"),
        (GOOD + '[geometry]\njunction_types = ["roundabout"]\n', r"junction_types: unknown type 'roundabout'"),
        (GOOD + "[traffic]\nvehicle_width_m = [0.0, 2.0]\n", r"traffic: vehicle_width_m: expected values > 0"),
        (GOOD + "[traffic]\nmax_actors = 0\n", r"max_actors: expected an integer >= 1"),
        (GOOD + "[traffic]\nmax_actors = 'many'\n", r"traffic\.max_actors: expected an integer"),
        ('seed = 1\nn_nets = 2\nkind = "roundabout"\n', r"kind: unknown kind 'roundabout'"),
        ('seed = 1\nn_nets = 2\nkind = ["fourway"]\n', r"kind: a list of kinds needs one per net: got 1 for n_nets=2"),
        ('seed = 1\nkind = "fourway"\n', r"fam\.toml: missing required key 'n_nets'"),
        (GOOD + 'name = "other"\n', r"fam\.toml\.name: 'other' differs from the file name 'fam'"),
    ],
)  # fmt: skip
def test_bad_family_toml_is_one_line_naming_file_and_field(tmp_path, text, pattern):
    with pytest.raises(PriqnError, match=pattern) as exc:
        load_family(_write(tmp_path, "fam", text))
    _one_line(exc)


def test_unknown_family_lists_the_known_ones():
    with pytest.raises(PriqnError, match=r"unknown scenario family 'tjunctoin' \(available: .*fourway.*holdout.*tjunction") as exc:  # fmt: skip
        load_family("tjunctoin")
    _one_line(exc)
    with pytest.raises(PriqnError, match="scenario file not found"):
        load_family("nowhere/fam.toml")


# --------------------------------------------------------------------------- generation


def test_plan_is_deterministic_in_the_seed_and_within_ranges():
    fam = load_family("fourway")
    plan = netgen.family_plan(fam)
    assert plan == netgen.family_plan(fam)
    other = netgen.family_plan(dataclasses.replace(fam, seed=fam.seed + 1))
    assert [p["params"] for p in plan] != [p["params"] for p in other]
    g = fam.geometry
    for entry in plan:
        p = entry["params"]
        assert entry["kind"] == p["kind"] == "fourway" and len(p["arm_angles_deg"]) == 4
        angles = np.sort(np.asarray(p["arm_angles_deg"]))
        gaps = np.diff(np.concatenate([angles, [angles[0] + 360.0]]))
        assert gaps.min() >= g.min_arm_separation_deg
        assert all(g.arm_length_m[0] <= x <= g.arm_length_m[1] for x in p["arm_lengths_m"])
        assert all(
            g.lanes_per_direction[0] <= n <= g.lanes_per_direction[1]
            for n in p["lanes_per_direction"]
        )
        assert g.lane_width_m[0] <= p["lane_width_m"] <= g.lane_width_m[1]
        assert g.speed_limit_mps[0] <= p["speed_limit_mps"] <= g.speed_limit_mps[1]
        assert p["junction_type"] in g.junction_types
    assert len({e["id"] for e in plan}) == len(plan)


def test_mixed_kind_draws_both_kinds(tmp_path):
    fam = load_family(_write(tmp_path, "mix", 'seed = 3\nn_nets = 12\nkind = "mixed"\n'))
    kinds = [e["kind"] for e in netgen.family_plan(fam)]
    assert set(kinds) == set(KINDS)


@pytest.mark.parametrize("family", FAMILIES)
def test_regenerating_gives_byte_identical_files(tmp_path, family):
    fam = load_family(family)
    committed = load_manifest(family)
    ids = [n["id"] for n in committed["nets"]][:3]  # every hold-out net; 3 per other family
    out = netgen.generate_family(fam, tmp_path, net_ids=ids)
    fresh = load_manifest(family, tmp_path)
    for new, old in zip(fresh["nets"], committed["nets"][: len(ids)], strict=True):
        assert new == old
        for name in new["files"]:
            assert (out / name).read_bytes() == (nets_dir() / family / name).read_bytes(), name
    assert {k: v for k, v in fresh.items() if k != "nets"} == {
        k: v for k, v in committed.items() if k != "nets"
    }


def test_netconvert_output_has_no_timestamp_and_keeps_internal_lanes():
    text = (nets_dir() / "holdout" / "fourway_00.net.xml").read_text(encoding="utf-8")
    assert "generated on" not in text
    assert 'function="internal"' in text
    assert '<no-turnarounds value="true"/>' in text


def test_netconvert_failure_is_one_line_priqn_error():
    params = netgen.family_plan(load_family("holdout"))[0]["params"]
    bad = {**params, "lanes_per_direction": [0, 1, 1]}
    with pytest.raises(
        PriqnError,
        match=r"netconvert for net 'bad' failed: Error: Edge 'a0_in' needs at least one lane",
    ) as exc:
        netgen.build_net("bad", bad)
    _one_line(exc)


# --------------------------------------------------------------------------- committed nets


@pytest.mark.parametrize("family", FAMILIES)
def test_committed_nets_match_manifest_and_load_with_sumolib(family):
    import sumolib

    manifest = load_manifest(family)
    fam = load_family(family)
    assert manifest["family"] == family and manifest["seed"] == fam.seed
    assert manifest["sumo_version"] == sumo.sumo_version()
    assert manifest["generator_version"] == netgen.GENERATOR_VERSION
    assert manifest["traffic"]["max_actors"] == fam.traffic.max_actors
    assert len(manifest["nets"]) == fam.n_nets
    assert netgen.verify_family_files(nets_dir() / family, manifest) == []
    for entry in manifest["nets"]:
        assert set(entry["files"]) == {f"{entry['id']}{s}" for s in netgen.NET_SUFFIXES}
        net = sumolib.net.readNet(
            str(nets_dir() / family / f"{entry['id']}.net.xml"), withInternal=True
        )
        arms = len(entry["params"]["arm_angles_deg"])
        assert arms == {"tjunction": 3, "fourway": 4}[entry["kind"]]
        assert len(net.getEdges(withInternal=False)) == 2 * arms
        assert net.getNode("J").getType() == entry["params"]["junction_type"]
        size = (nets_dir() / family / f"{entry['id']}.net.xml").stat().st_size
        assert size < 100_000, "a single-junction net should be tens of KB"


def test_holdout_is_disjoint_from_training():
    train = [n for f in TRAINING for n in load_manifest(f)["nets"]]
    hold = load_manifest("holdout")["nets"]
    assert [n["kind"] for n in hold].count("tjunction") == 1
    assert [n["kind"] for n in hold].count("fourway") == 2
    train_params = [n["params"] for n in train]
    train_files = {sha for n in train for sha in n["files"].values()}
    for net in hold:
        assert net["params"] not in train_params
        assert not set(net["files"].values()) & train_files
        # Not even one arm layout repeats.
        layouts = {tuple(p["arm_angles_deg"]) for p in train_params}
        assert tuple(net["params"]["arm_angles_deg"]) not in layouts
    all_params = [n["params"] for n in train]
    assert len({repr(p) for p in all_params}) == len(all_params)


def test_out_of_range_family_is_disjoint_and_outside_the_training_ranges():
    """Every out-of-range net is new (no training or hold-out net's parameters, files or arm
    layout) and lies outside the training ranges in lane width and junction radius; half
    the nets have 3 lanes per direction; its 2^(4-1) design is balanced (its header)."""
    others = [n for f in ("tjunction", "fourway", "holdout") for n in load_manifest(f)["nets"]]
    oor = load_manifest("out-of-range")["nets"]
    assert len(oor) == 8
    assert [n["kind"] for n in oor].count("tjunction") == 4
    assert [n["kind"] for n in oor].count("fourway") == 4
    train = load_family("tjunction").geometry
    assert train == load_family("fourway").geometry == load_family("holdout").geometry
    other_files = {sha for n in others for sha in n["files"].values()}
    layouts = {tuple(n["params"]["arm_angles_deg"]) for n in others}
    levels = []
    for net in oor:
        p = net["params"]
        assert not set(net["files"].values()) & other_files
        assert tuple(p["arm_angles_deg"]) not in layouts
        wide = p["lane_width_m"] > train.lane_width_m[1]
        assert wide or p["lane_width_m"] < train.lane_width_m[0], net["id"]
        large = p["junction_radius_m"] > train.junction_radius_m[1]
        assert large or p["junction_radius_m"] < train.junction_radius_m[0], net["id"]
        three = set(p["lanes_per_direction"]) == {3}
        assert three or max(p["lanes_per_direction"]) <= train.lanes_per_direction[1]
        levels.append((net["kind"] == "fourway", wide, large, three))
    # Each level of each feature on 4 nets, each pair of levels of two features on 2.
    for i in range(4):
        assert sum(lv[i] for lv in levels) == 4
        for j in range(i + 1, 4):
            assert Counter((lv[i], lv[j]) for lv in levels) == dict.fromkeys(
                [(False, False), (False, True), (True, False), (True, True)], 2
            )
    assert {n["params"]["junction_type"] for n in oor} == {"priority", "right_before_left"}


def test_net_geometry_changes_one_net_and_is_checked(tmp_path):
    text = (
        'seed = 7\nn_nets = 2\nkind = "fourway"\n[geometry]\nlane_width_m = [3.0, 3.6]\n'
        "[[net_geometry]]\nlane_width_m = [2.6, 2.9]\n[[net_geometry]]\n"
    )
    fam = load_family(_write(tmp_path, "two", text))
    assert fam.geometry_of(0).lane_width_m == (2.6, 2.9)
    assert fam.geometry_of(1) == fam.geometry
    plan = netgen.family_plan(fam)
    assert 2.6 <= plan[0]["params"]["lane_width_m"] <= 2.9
    assert 3.0 <= plan[1]["params"]["lane_width_m"] <= 3.6
    # Without net_geometry the draws are as before (the committed nets stay byte for byte:
    # test_regenerating_gives_byte_identical_files); the override changes only its field.
    plain = netgen.family_plan(dataclasses.replace(fam, net_geometry=()))
    assert plain[1] == plan[1]
    assert {k: v for k, v in plain[0]["params"].items() if k != "lane_width_m"} == {
        k: v for k, v in plan[0]["params"].items() if k != "lane_width_m"
    }
    netgen.generate_family(fam, tmp_path / "nets")
    manifest = load_manifest("two", tmp_path / "nets")
    assert manifest["net_geometry"] == [{"lane_width_m": [2.6, 2.9]}, {}]
    assert "net_geometry" not in load_manifest("holdout")


@pytest.mark.parametrize(
    ("tables", "pattern"),
    [
        ("[[net_geometry]]\n", r"fam\.toml: net_geometry: needs one table per net: got 1 for n_nets=2"),
        ("[[net_geometry]]\nlane_width_m = [3.0]\n[[net_geometry]]\n", r"fam\.toml: net_geometry\[0\]: lane_width_m: expected a range"),
        ("[[net_geometry]]\n[[net_geometry]]\nlane_widht_m = [3.0, 3.2]\n", r"net_geometry\[1\]: unknown key 'lane_widht_m'"),
        ("[[net_geometry]]\n[[net_geometry]]\narm_angle_jitter_deg = 30.0\n", r"net_geometry\[1\]: .*arm_angle_jitter_deg: 30\.0 lets arms come 30 deg close"),
    ],
)  # fmt: skip
def test_bad_net_geometry_is_one_line(tmp_path, tables, pattern):
    with pytest.raises(PriqnError, match=pattern) as exc:
        load_family(_write(tmp_path, "fam", GOOD + tables))
    _one_line(exc)


def test_manifest_hash_is_sha256_of_sorted_file_lines():
    manifest = load_manifest("holdout")
    lines = sorted(
        f"{n['id']}/{name} {sha}" for n in manifest["nets"] for name, sha in n["files"].items()
    )
    assert manifest_hash("holdout") == hashlib.sha256("\n".join(lines).encode()).hexdigest()
    changed = {
        **manifest,
        "nets": [dict(manifest["nets"][0], files={"x": "0"}), *manifest["nets"][1:]],
    }
    assert hash_of_manifest(changed) != manifest_hash("holdout")
    assert manifest_hash("tjunction") != manifest_hash("fourway")


def test_net_refs_and_missing_net_error(tmp_path, monkeypatch):
    # The shipped nets: from a folder without its own ./sumo_nets (the README's first
    # command writes one into the checkout, and a ./sumo_nets is searched first).
    monkeypatch.chdir(tmp_path)
    assert set(FAMILIES) <= set(list_generated())
    refs = family_net_refs("holdout")
    assert refs == ["holdout/tjunction_00", "holdout/fourway_00", "holdout/fourway_01"]
    assert net_path("holdout/fourway_01") == nets_dir() / "holdout" / "fourway_01.net.xml"
    assert net_path(str(net_path("holdout/fourway_01"))).is_file()
    with pytest.raises(PriqnError) as exc:
        net_path("holdout/foo")
    msg = _one_line(exc)
    assert msg.startswith(
        "sumo_nets/holdout/foo.net.xml: no such net; run 'priqn scenario generate'"
    )
    assert "pick one of: " in msg and "holdout/fourway_00" in msg
    with pytest.raises(PriqnError, match="expected 'family/net_id'"):
        net_path("fourway_00")
    with pytest.raises(PriqnError, match="no manifest for family 'nofam'"):
        load_manifest("nofam")
    with pytest.raises(PriqnError, match=r"; did you mean 'out-of-range'\?$"):
        load_manifest("out-of-rang")


# --------------------------------------------------------------------------- CLI


def _priqn(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=120,
    )


def test_cli_bad_toml_and_missing_net_are_one_line(tmp_path):
    bad = _write(tmp_path, "bad", GOOD + "[traffic]\nmax_actor = 3\n")
    res = _priqn("scenario", "generate", "--family", str(bad), "--out", str(tmp_path / "nets"))
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0
    assert "bad.toml.traffic: unknown key 'max_actor'" in res.stderr
    assert not (tmp_path / "nets").exists()
    res = _priqn("scenario", "show", "holdout/nope")
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0
    assert "sumo_nets/holdout/nope.net.xml: no such net" in res.stderr


def test_cli_generate_to_folder_and_check(tmp_path):
    fam = _write(tmp_path, "tiny", 'seed = 5\nn_nets = 2\nkind = ["tjunction", "fourway"]\n')
    out = tmp_path / "nets"
    res = _priqn("scenario", "generate", "--family", str(fam), "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in (out / "tiny").iterdir()) == [
        "fourway_00.edg.xml", "fourway_00.net.xml", "fourway_00.nod.xml", "manifest.json",
        "tjunction_00.edg.xml", "tjunction_00.net.xml", "tjunction_00.nod.xml",
    ]  # fmt: skip
    res = _priqn("scenario", "generate", "--family", str(fam), "--out", str(out), "--check")
    assert res.returncode == 0, res.stderr
    assert "tiny: 2 nets match the committed manifest" in res.stdout
    (out / "tiny" / "fourway_00.net.xml").write_text("tampered", encoding="utf-8")
    res = _priqn("scenario", "generate", "--family", str(fam), "--out", str(out), "--check")
    assert res.returncode == 2
    assert "fourway_00.net.xml: SHA-256 differs from the manifest" in res.stderr


def test_missing_manifest_lists_the_families_of_that_folder(tmp_path):
    from priqn.errors import PriqnError
    from priqn.sim.scenario import load_manifest

    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "manifest.json").write_text('{"nets": []}')
    with pytest.raises(PriqnError, match=r"generated families: mine\)"):
        load_manifest("tjunction", tmp_path)
    with pytest.raises(PriqnError, match=r"generated families: none\)"):
        load_manifest("tjunction", tmp_path / "mine")


def test_hand_made_manifest_without_hashes_is_one_line(tmp_path) -> None:
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "manifest.json").write_text('{"nets": [{"id": "a"}]}')
    with pytest.raises(PriqnError) as info:
        load_manifest("mine", tmp_path)
    msg = str(info.value)
    assert "\n" not in msg and "nets[0] needs an 'id' and the SHA-256 of its 'files'" in msg
    assert "env.nets" in msg
