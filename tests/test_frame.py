"""The shared frame: config loading, atomic writes, CLI error handling."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from priqn.config import (
    apply_overrides,
    apply_values,
    describe,
    dumps_toml,
    from_dict,
    load_toml,
    parse_override,
    to_dict,
    toml_value,
    value_pairs,
)
from priqn.errors import PriqnError
from priqn.io import atomic_write_json, atomic_write_text


@dataclasses.dataclass(frozen=True)
class Inner:
    lr: float = 1e-3
    """Learning rate."""
    names: tuple[str, ...] = ("a", "b")
    """Some names."""


@dataclasses.dataclass(frozen=True)
class Outer:
    seed: int = 0
    """Master seed."""
    inner: Inner = dataclasses.field(default_factory=Inner)
    """Nested section."""
    mode: str = "x"
    """A mode."""


def test_from_dict_roundtrip_and_coercion():
    cfg = from_dict(Outer, {"seed": 3, "inner": {"lr": 1, "names": ["p"]}}, "t.toml")
    assert cfg == Outer(seed=3, inner=Inner(lr=1.0, names=("p",)))
    assert from_dict(Outer, to_dict(cfg), "x") == cfg


def test_unknown_key_names_file_field_and_valid_keys():
    with pytest.raises(PriqnError, match=r"t.toml.inner: unknown key 'lrr' \(valid: lr, names\)"):
        from_dict(Outer, {"inner": {"lrr": 1}}, "t.toml")


def test_wrong_type_is_one_line():
    with pytest.raises(PriqnError, match=r"t.toml.seed: expected an integer, got 'a'"):
        from_dict(Outer, {"seed": "a"}, "t.toml")


def test_overrides():
    cfg = apply_overrides(Outer(), ["inner.lr=0.5", "mode=fast"])
    assert cfg.inner.lr == 0.5 and cfg.mode == "fast"
    with pytest.raises(PriqnError, match="unknown key 'inner.nope'"):
        apply_overrides(Outer(), ["inner.nope=1"])


def test_apply_values_sets_typed_values_in_order():
    pairs = [("inner.names", ["p", "q"]), ("seed", 4), ("inner.lr", 1), ("seed", 5)]
    cfg = apply_values(Outer(), pairs, "grid.toml (row)")
    assert cfg == Outer(seed=5, inner=Inner(lr=1.0, names=("p", "q")))
    assert apply_values(Outer(), {"mode": "fast", "inner.names": ("z",)}) == Outer(
        mode="fast", inner=Inner(names=("z",))
    )
    # typed values and --set strings in one pass: the later wins, the whole is checked once
    assert apply_values(Outer(), [("seed", 1), "seed=2", "mode=a b"]) == Outer(seed=2, mode="a b")
    assert apply_overrides(Outer(), ["inner.names=['x']"]).inner.names == ("x",)


def test_apply_values_errors_name_the_key_and_the_valid_ones():
    with pytest.raises(
        PriqnError, match=r"^grid.toml \(row\): unknown key 'inner.nope' \(valid here: lr, names\)$"
    ):
        apply_values(Outer(), [("inner.nope", 1)], "grid.toml (row)")
    with pytest.raises(PriqnError, match=r"^w: 'seed.x' is not a config field$"):
        apply_values(Outer(), [("seed.x", 1)], "w")
    with pytest.raises(PriqnError, match=r"^w.inner.lr: expected a number, got 'fast'$"):
        apply_values(Outer(), [("inner.lr", "fast")], "w")
    with pytest.raises(PriqnError, match=r"expected \(KEY, VALUE\) pairs, got \('seed', 1, 2\)"):
        apply_values(Outer(), [("seed", 1, 2)], "w")
    # a --set string is named as it was typed
    with pytest.raises(PriqnError, match=r"^--set 'inner.nope=1': unknown key 'inner.nope'"):
        apply_overrides(Outer(), ["seed=1", "inner.nope=1"])
    with pytest.raises(PriqnError, match=r"^--set 'seed': expected KEY=VALUE"):
        apply_values(Outer(), [("seed", 1), "seed"])


def test_values_as_toml_text_parse_back_equal():
    """toml_value (the text a child at an older commit reads) parses back to the value."""
    tricky = [
        0.2, 1e-05, -0.0, 1e16, 7, True, False, "hln-4", "a 'quoted' \"x\"\\ y", "é ✓ 🚗",
        "\x7f\n\t", (60000, 120000), ["safety", "risk"], [], {"a": [1, 2.5], "b c": "d"},
    ]  # fmt: skip
    for value in tricky:
        key, back = parse_override(f"k={toml_value(value)}")
        assert key == "k" and value_pairs([(key, back)]) == value_pairs([("k", value)]), value
    assert value_pairs({"k": [1, [2]]}) == (("k", (1, (2,))),)


def test_describe_reads_field_docstrings():
    rows = {k: doc for k, _, doc in describe(Outer)}
    assert rows["inner.lr"] == "Learning rate."
    assert rows["seed"] == "Master seed."


def test_toml_roundtrip(tmp_path: Path):
    p = tmp_path / "c.toml"
    atomic_write_text(p, dumps_toml(to_dict(Outer(seed=7))))
    assert from_dict(Outer, load_toml(p), str(p)) == Outer(seed=7)


def test_malformed_and_missing_toml(tmp_path: Path):
    bad = tmp_path / "bad.toml"
    bad.write_text("a = [1,\n")
    with pytest.raises(PriqnError, match="bad.toml: malformed TOML"):
        load_toml(bad)
    with pytest.raises(PriqnError, match="nope.toml: file not found"):
        load_toml(tmp_path / "nope.toml")


def test_atomic_write_keeps_old_file_on_failure(tmp_path: Path):
    p = tmp_path / "m.json"
    atomic_write_json(p, {"a": 1})
    with pytest.raises(TypeError):
        from priqn.io import atomic_open

        with atomic_open(p, "w") as fh:
            fh.write("partial")
            raise TypeError("boom")
    assert p.read_text() == '{\n  "a": 1\n}\n'
    assert [x.name for x in tmp_path.iterdir()] == ["m.json"]


def test_cli_unknown_command_and_help():
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "--help"], capture_output=True, text=True
    )
    assert out.returncode == 0 and "scenario" in out.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "nope"], capture_output=True, text=True
    )
    assert bad.returncode == 2 and "unknown command 'nope'" in bad.stderr


@dataclasses.dataclass(frozen=True)
class Pair:
    range_m: tuple[float, float] = (0.0, 1.0)
    """A (lo, hi) range."""


def test_fixed_length_tuple_coerces_values_not_types():
    assert from_dict(Pair, {"range_m": [1, 2.5]}, "p").range_m == (1.0, 2.5)
    with pytest.raises(PriqnError, match="expected 2 values"):
        from_dict(Pair, {"range_m": [1]}, "p")


def test_atomic_files_get_umask_mode(tmp_path: Path):
    import os
    import stat

    p = tmp_path / "f.txt"
    atomic_write_text(p, "x")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask


@dataclasses.dataclass(frozen=True)
class WithLiteral:
    stat: typing.Literal["mean", "iqm"] | None = None
    """A statistic, or none."""


def test_optional_literal_error_lists_allowed_values():
    assert from_dict(WithLiteral, {"stat": "iqm"}, "w").stat == "iqm"
    with pytest.raises(PriqnError, match=r"w.stat: expected one of 'mean', 'iqm', got 'median'"):
        from_dict(WithLiteral, {"stat": "median"}, "w")


def test_stale_temp_files_of_killed_writes_are_removed(tmp_path):
    from priqn.io import atomic_write_text, remove_stale_temp_files

    atomic_write_text(tmp_path / "meta.json", "{}")
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / ".meta.json.k3j2x9.tmp").write_bytes(b"")  # what kill -9 mid-write leaves
    (tmp_path / "checkpoints" / ".latest.pt.a81bq0.tmp").write_bytes(b"partial")
    (tmp_path / "notes.tmp").write_text("a user's file, not ours")
    assert remove_stale_temp_files(tmp_path) == 2
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["checkpoints", "meta.json", "notes.tmp"]
