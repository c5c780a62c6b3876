"""The checkpoint format (:mod:`priqn.run.checkpoint`): round trips, the keys on disk, and
one-line errors for damaged or foreign files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from priqn.errors import PriqnError
from priqn.io import CHECKSUM_SUFFIX, atomic_torch_save
from priqn.objectives import OBJECTIVES
from priqn.run import checkpoint
from priqn.run.checkpoint import Checkpoint, PolicyState
from priqn.run.checkpointer import load_checkpoint, replay_files, save_checkpoint
from priqn.run.folder import RunFolder

CHECKPOINT_KEYS = [
    "step", "episodes", "wall_s", "learner", "rng_replay", "rng_act", "obs", "obs_shapes",
    "num_actions", "config", "replay_file", "torch_version", "objectives",
    "replay_chunks", "in_flight", "logging",
]  # fmt: skip
"""The keys of checkpoints/latest.pt since the first release (old files must keep loading),
then the optional ``objectives`` (declared objectives; absent = the default five) and the
optional parts of an exact resume (issue 49: replay chunks, episodes in flight, logging)."""
POLICY_KEYS = ["online", "agent", "obs_shapes", "num_actions", "step", "objectives"]
"""The keys of policy.pt (``agent`` and ``objectives`` optional); both files end in
``format`` since issue 35 (absent: format 1)."""


def safe_load(path: Path) -> dict:
    """The raw on-disk dict, read the only way priqn reads torch files (weights only)."""
    return torch.load(path, weights_only=True)


def make_checkpoint(step: int = 40) -> Checkpoint:
    net = torch.nn.Linear(3, 2)
    generator = torch.Generator().manual_seed(5)
    rng_replay, rng_act = np.random.default_rng(1), np.random.default_rng(2)
    rng_act.random(3)
    return Checkpoint(
        step=step,
        episodes=3,
        wall_s=12.5,
        learner={
            "online": net.state_dict(),
            "target": net.state_dict(),
            "optimizer": torch.optim.Adam(net.parameters()).state_dict(),
            "updates": 7,
            "tau_generator": generator.get_state(),
            "agent": {"scale": {"mean": torch.ones(5)}},
        },
        rng_replay=rng_replay.bit_generator.state,
        rng_act=rng_act.bit_generator.state,
        obs={"bev": np.arange(24, dtype=np.uint8).reshape(2, 3, 4)},
        obs_shapes={"bev": ([3, 4], "uint8", 255.0)},
        num_actions=25,
        config={"seed": 7, "agent": {"name": "pr-iqn"}},
    )


def assert_same(a: Checkpoint, b: Checkpoint) -> None:
    assert (a.step, a.episodes, a.wall_s, a.num_actions) == (b.step, b.episodes, b.wall_s, 25)
    for key in ("online", "target"):
        for name, tensor in a.learner[key].items():
            assert torch.equal(tensor, b.learner[key][name]), (key, name)
    assert torch.equal(a.learner["tau_generator"], b.learner["tau_generator"])
    assert torch.equal(a.learner["agent"]["scale"]["mean"], b.learner["agent"]["scale"]["mean"])
    assert a.learner["updates"] == b.learner["updates"] == 7
    assert a.rng_replay == b.rng_replay and a.rng_act == b.rng_act
    assert np.array_equal(a.obs["bev"], b.obs["bev"]) and b.obs["bev"].dtype == np.uint8
    assert a.obs_shapes == b.obs_shapes and a.config == b.config


def test_checkpoint_round_trip_keeps_every_field_and_the_keys_on_disk(tmp_path: Path) -> None:
    path = tmp_path / "ckpt" / "latest.pt"
    state = make_checkpoint()
    checkpoint.save(state, path)
    back = checkpoint.load(path)
    assert_same(state, back)
    assert back.replay_file is None and back.torch_version == torch.__version__
    # The generators continue where they were.
    rng = np.random.default_rng()
    rng.bit_generator.state = back.rng_act
    expected = np.random.default_rng(2)
    expected.random(3)
    assert rng.random() == expected.random()
    # On disk: the same plain dict of the same keys as ever, then the format version;
    # tensors and plain data only (the observations as tensors); a SHA-256 sidecar, and
    # no temp file left behind.
    raw = safe_load(path)
    assert list(raw) == [*CHECKPOINT_KEYS, "format"] and raw["format"] == checkpoint.FORMAT_VERSION
    assert isinstance(raw["obs"]["bev"], torch.Tensor) and type(raw["torch_version"]) is str
    assert Path(str(path) + CHECKSUM_SUFFIX).is_file()
    assert sorted(p.name for p in path.parent.iterdir()) == ["latest.pt", "latest.pt.sha256"]


def test_a_checkpoint_written_by_the_old_code_still_loads(tmp_path: Path) -> None:
    """The dict train.py and RunFolder.save_checkpoint wrote before this module existed."""
    state = make_checkpoint()
    old = {k: getattr(state, k) for k in CHECKPOINT_KEYS[:-3]}
    path = tmp_path / "latest.pt"
    atomic_torch_save(dict(old, replay_file="replay-000000000040.npz", torch_version="2.0"), path)
    back = checkpoint.load(path)
    assert_same(state, back)
    assert back.replay_file == "replay-000000000040.npz" and back.torch_version == "2.0"
    # Without the optional keys (and without a sidecar) too.
    torch.save(old, path)
    Path(str(path) + CHECKSUM_SUFFIX).unlink()
    assert checkpoint.load(path).replay_file is None
    assert tuple(checkpoint.load(path).objectives) == OBJECTIVES  # before declared objectives


def test_policy_state_round_trip_and_from_a_checkpoint(tmp_path: Path) -> None:
    state = make_checkpoint(step=80)
    policy = state.policy_state()
    assert isinstance(policy, PolicyState) and policy.step == 80 and policy.num_actions == 25
    assert policy.agent == state.learner["agent"] and policy.online is state.learner["online"]
    path = tmp_path / "policy.pt"
    checkpoint.save(policy, path)
    assert list(safe_load(path)) == [*POLICY_KEYS, "format"]
    back = checkpoint.load_policy_state(path)
    assert back.step == 80 and back.obs_shapes == state.obs_shapes
    for name, tensor in policy.online.items():
        assert torch.equal(tensor, back.online[name])
    # An older policy.pt without the agent's state reads as an empty one.
    torch.save({k: v for k, v in safe_load(path).items() if k not in ("agent", "format")}, path)
    Path(str(path) + CHECKSUM_SUFFIX).unlink()
    assert checkpoint.load_policy_state(path).agent == {}


def one_line_error(path: Path, **kw) -> str:
    with pytest.raises(PriqnError) as info:
        checkpoint.load(path, **kw)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    # No torch traceback chained to it.
    exc = info.value
    assert exc.__cause__ is None and (exc.__context__ is None or exc.__suppress_context__)
    return msg


@pytest.mark.parametrize("sidecar", [True, False])
@pytest.mark.parametrize("damage", ["truncate", "empty", "flip"])
def test_a_damaged_checkpoint_is_one_line_naming_the_file(
    tmp_path: Path, damage: str, sidecar: bool
) -> None:
    path = tmp_path / "latest.pt"
    checkpoint.save(make_checkpoint(), path)
    if not sidecar:
        Path(str(path) + CHECKSUM_SUFFIX).unlink()
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "empty":
        data = bytearray()
    else:
        data[len(data) // 3 : len(data) // 3 + 64] = bytes(64)
    path.write_bytes(bytes(data))
    if damage == "flip" and not sidecar:
        # Zeroed bytes inside a tensor's storage are not detectable without the sidecar;
        # a zeroed zip header is.
        data[:64] = bytes(64)
        path.write_bytes(bytes(data))
    msg = one_line_error(path, remedy="train again")
    assert "damaged or unreadable checkpoint" in msg and msg.endswith("; train again")


def test_a_foreign_torch_file_is_not_a_checkpoint(tmp_path: Path) -> None:
    path = tmp_path / "latest.pt"
    torch.save([1, 2, 3], path)
    assert "not a priqn checkpoint (a list)" in one_line_error(path)
    torch.save({"step": 1, "learner": {}}, path)
    msg = one_line_error(path)
    assert "not a priqn checkpoint (no episodes, wall_s, rng_replay" in msg
    with pytest.raises(PriqnError, match="not a priqn policy file"):
        checkpoint.load_policy_state(path)


def _replay_with(rows_per_env: int, capacity: int = 12):
    """A 2-env buffer of 1-byte frames whose row p of env e holds 10 * e + p."""
    from priqn.agents.replay import ReplayBuffer

    replay = ReplayBuffer({"x": ((1,), np.uint8)}, num_envs=2, capacity=capacity)
    for p in range(rows_per_env):
        obs = {"x": np.array([[p], [10 + p]], np.uint8)}
        replay.add(obs, np.array([p, p]), np.zeros((2, 5)), np.zeros(2, bool),
                   np.zeros(2, bool), [None, None])  # fmt: skip
    return replay


def test_replay_chunks_are_written_first_named_and_dropped_once_overwritten(
    tmp_path: Path,
) -> None:
    from priqn.agents.replay import ReplayBuffer

    run = RunFolder(tmp_path / "run")
    # Rings of 6 rows per env. Checkpoint 1 after 4 rows, 2 after 8 (rows 4-7), 3 after 12
    # (rows 8-11): every row of chunk 1 (rows 0-3) is overwritten by then, chunk 2's rows
    # 6 and 7 are not.
    saved = save_checkpoint(run, make_checkpoint(step=40), _replay_with(4))
    assert saved.replay_chunks == [{"file": "replay-000000000040.npz", "end": [4, 4]}]
    saved = save_checkpoint(
        run,
        dataclasses.replace(make_checkpoint(step=80), replay_chunks=saved.replay_chunks),
        _replay_with(8),
    )
    replay = _replay_with(12)
    saved = save_checkpoint(
        run,
        dataclasses.replace(make_checkpoint(step=120), replay_chunks=saved.replay_chunks),
        replay,
    )
    back = load_checkpoint(run, "cpu")
    assert [c["file"] for c in back.replay_chunks] == [
        "replay-000000000080.npz",
        "replay-000000000120.npz",
    ]
    assert sorted(p.name for p in run.checkpoint_dir.glob("replay-*.npz")) == [
        c["file"] for c in back.replay_chunks
    ]
    fresh = ReplayBuffer({"x": ((1,), np.uint8)}, num_envs=2, capacity=12)
    for path in replay_files(run, back):
        fresh.load_rows(path)
    assert fresh.written.tolist() == [12, 12]
    assert np.array_equal(fresh.obs["x"], replay.obs["x"])  # rows 6-11 of each env
    assert fresh.obs["x"][1, :, 0].tolist() == [16, 17, 18, 19, 20, 21]
    assert np.array_equal(fresh.action, replay.action) and np.array_equal(
        fresh.starts, replay.starts
    )
    save_checkpoint(run, make_checkpoint(step=160), None)  # checkpoint.save_replay = false
    back = load_checkpoint(run, "cpu")
    assert back.replay_chunks is None and replay_files(run, back) == []
    assert not list(run.checkpoint_dir.glob("replay-*.npz"))
    run.latest_checkpoint.write_bytes(b"")
    with pytest.raises(PriqnError, match=r"latest\.pt: damaged or unreadable checkpoint"):
        load_checkpoint(run, "cpu")
