"""Model files: a round trip keeps the actor, bad or tampered files get a clear ModelError.

A model file must never run code on loading: its weights are read with torch's
weights-only unpickler, so a pickle that would run a callable is refused.
"""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from pathlib import Path

import pytest
import torch

from rlpgo_gtsam.errors import ModelError, OutputError
from rlpgo_gtsam.rl.agent.checkpoint import FORMAT_VERSION, load_model, save_model
from rlpgo_gtsam.rl.agent.networks import Actor
from rlpgo_gtsam.rl.env import PRESETS

HIDDEN = 16


def _actor(hidden: int = HIDDEN, seed: int = 0) -> Actor:
    torch.manual_seed(seed)
    return Actor(hidden)


@pytest.fixture
def model(tmp_path) -> Path:
    """A valid model file of a hidden-16 actor for preset 3."""
    path = tmp_path / "model.zip"
    save_model(path, _actor(), PRESETS[3], {"seed": 5, "preset": 3})
    return path


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def _rewrite(src: Path, dst: Path, changes: dict[str, bytes | str | None]) -> Path:
    """Copy the zip ``src`` to ``dst`` with members replaced (``None``: removed)."""
    members = _members(src)
    members.update(changes)
    with zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            if data is not None:
                zf.writestr(name, data)
    return dst


def _config(path: Path) -> dict:
    return json.loads(_members(path)["config.json"])


def _state_bytes(actor: Actor) -> bytes:
    buffer = io.BytesIO()
    torch.save(actor.state_dict(), buffer)
    return buffer.getvalue()


# --- round trip -------------------------------------------------------------------------


def test_round_trip_keeps_outputs_env_and_metadata(model):
    loaded = load_model(model)
    original = _actor()
    torch.manual_seed(1)
    observation, last_action = torch.randn(2, 7, 4), torch.rand(2, 7, 2) * 2 - 1
    with torch.no_grad():
        expected, _ = original.deterministic(observation, last_action)
        actual, _ = loaded.actor.deterministic(observation, last_action)
    assert torch.allclose(actual, expected)
    assert loaded.env_config == PRESETS[3]
    assert loaded.metadata["seed"] == 5
    assert loaded.metadata["preset"] == 3
    assert loaded.metadata["format"] == FORMAT_VERSION
    assert loaded.metadata["hidden"] == HIDDEN
    assert _config(model)["format"] == FORMAT_VERSION
    assert loaded.path == model
    assert not loaded.actor.training


def test_load_accepts_a_str_path(model):
    assert load_model(str(model)).actor.trunk.hidden == HIDDEN


def test_model_file_is_a_zip_of_config_and_weights_only(model):
    assert sorted(_members(model)) == ["actor.pt", "config.json"]


# --- tampered weights never run code ------------------------------------------------------


class _Touch:
    """Unpickling this object creates ``marker``: a stand-in for arbitrary code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _torch_payload(marker: Path) -> bytes:
    buffer = io.BytesIO()
    torch.save({"trunk.encoder.beta": _Touch(marker)}, buffer)
    return buffer.getvalue()


def _pickle_payload(marker: Path) -> bytes:
    return pickle.dumps(_Touch(marker), protocol=2)


def _unsafe_load(payload: bytes) -> None:
    try:
        pickle.loads(payload)
    except pickle.UnpicklingError:  # a torch zip, not a raw pickle
        torch.load(io.BytesIO(payload), weights_only=False)


@pytest.mark.parametrize("make_payload", [_torch_payload, _pickle_payload],
                         ids=["torch.save", "pickle.dumps"])
def test_tampered_weights_are_refused_and_never_run(model, tmp_path, make_payload):
    # The payload is live: an unsafe load does create its marker.
    control = tmp_path / "control"
    _unsafe_load(make_payload(control))
    assert control.exists()

    marker = tmp_path / "pwned"
    tampered = _rewrite(model, tmp_path / "tampered.zip", {"actor.pt": make_payload(marker)})
    with pytest.raises(ModelError, match="safe loader") as error:
        load_model(tampered)
    assert "tampered.zip" in str(error.value)
    assert "\n" not in str(error.value)
    assert "weights_only" not in str(error.value)  # torch's advice to turn the safety off
    assert not marker.exists()


# --- bad files ----------------------------------------------------------------------------


def test_truncated_zip(model, tmp_path):
    data = model.read_bytes()
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match="not a readable model zip"):
        load_model(truncated)


def test_empty_file(tmp_path):
    empty = tmp_path / "empty.zip"
    empty.write_bytes(b"")
    with pytest.raises(ModelError, match="not a readable model zip"):
        load_model(empty)


def test_missing_file(tmp_path):
    with pytest.raises(ModelError, match="no such model file"):
        load_model(tmp_path / "absent.zip")


def test_directory_is_not_a_model(tmp_path):
    with pytest.raises(ModelError, match="no such model file"):
        load_model(tmp_path)


@pytest.mark.parametrize("member", ["config.json", "actor.pt"])
def test_zip_without_a_member(model, tmp_path, member):
    broken = _rewrite(model, tmp_path / "broken.zip", {member: None})
    with pytest.raises(ModelError, match=r"not an rlpgo model \(needs config.json and actor.pt\)"):
        load_model(broken)


def test_other_format_version(model, tmp_path):
    config = {**_config(model), "format": 2}
    newer = _rewrite(model, tmp_path / "newer.zip", {"config.json": json.dumps(config)})
    with pytest.raises(ModelError, match=r"format 2, this version reads format 1"):
        load_model(newer)


def test_config_without_format(model, tmp_path):
    config = _config(model)
    del config["format"]
    old = _rewrite(model, tmp_path / "old.zip", {"config.json": json.dumps(config)})
    with pytest.raises(ModelError, match=r"format None, this version reads format 1"):
        load_model(old)


@pytest.mark.parametrize("text", [b"{not json", b"\xff\xfe\x00garbage", b""],
                         ids=["syntax", "binary", "empty"])
def test_config_not_json(model, tmp_path, text):
    broken = _rewrite(model, tmp_path / "broken.zip", {"config.json": text})
    with pytest.raises(ModelError, match="config.json is not valid JSON"):
        load_model(broken)


def test_config_not_an_object(model, tmp_path):
    broken = _rewrite(model, tmp_path / "broken.zip", {"config.json": "[1, 2]"})
    with pytest.raises(ModelError, match="config.json is not a JSON object"):
        load_model(broken)


def test_weights_of_another_size(tmp_path):
    path = tmp_path / "big.zip"
    save_model(path, _actor(32), PRESETS[1], {})
    assert _config(path)["hidden"] == 32
    mismatched = _rewrite(path, tmp_path / "mismatched.zip",
                          {"actor.pt": _state_bytes(_actor(16))})
    with pytest.raises(ModelError, match="weights do not match the config") as error:
        load_model(mismatched)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    "change",
    [({"hidden": "wide"}, "hidden size must be an integer"),
     ({"hidden": None}, "hidden size must be an integer"),
     ({"hidden": -1}, "hidden size must be an integer"),
     ({"env": {"bogus": 1}}, "unknown env field"),
     ({"env": [1, 2]}, "config field env must be an object"),
     ({"env": None}, "config field env must be an object"),
     ({"test_cycles": float("inf")}, "config field test_cycles must be an integer"),
     ({"test_cycles": 10**12}, "config field test_cycles must be an integer"),
     ({"env": {"action_range_rad": "abc"}}, "env.action_range_rad must be a finite number"),
     ({"env": {"cycles": float("nan")}}, "config field env.cycles must be an integer"),
     ({"env": {"noisy_measurements": 1}}, "env.noisy_measurements must be true or false")],
    ids=["hidden-str", "hidden-null", "hidden-negative", "env-unknown-key", "env-list",
         "env-null", "test-cycles-inf", "test-cycles-huge",
         "action-range-str", "cycles-nan", "noisy-int"],
)
def test_bad_config_values(model, tmp_path, change):
    change, expected = change
    config = _config(model)
    if isinstance(change.get("env"), dict) and "bogus" not in change["env"]:
        change = {"env": {**config["env"], **change["env"]}}
    broken = _rewrite(model, tmp_path / "broken.zip",
                      {"config.json": json.dumps({**config, **change})})
    with pytest.raises(ModelError, match=expected):
        load_model(broken)


def test_a_5000_digit_integer_is_refused(model, tmp_path):
    text = json.dumps(_config(model))[:-1] + ', "test_cycles": ' + "9" * 5000 + "}"
    broken = _rewrite(model, tmp_path / "broken.zip", {"config.json": text})
    with pytest.raises(ModelError, match="not valid JSON"):
        load_model(broken)


def test_non_finite_weights_are_refused(tmp_path):
    actor = Actor(8)
    with torch.no_grad():
        actor.mean.bias.fill_(float("nan"))
    path = tmp_path / "nan.zip"
    save_model(path, actor, PRESETS[1], {})
    with pytest.raises(ModelError, match="NaN or infinite"):
        load_model(path)


@pytest.mark.parametrize("key", ["hidden", "env"])
def test_config_without_a_required_key(model, tmp_path, key):
    config = _config(model)
    del config[key]
    broken = _rewrite(model, tmp_path / "broken.zip", {"config.json": json.dumps(config)})
    expected = "hidden size must be an integer" if key == "hidden" else \
        "config field env must be an object"
    with pytest.raises(ModelError, match=expected):
        load_model(broken)


def _torch_bytes(value) -> bytes:
    buffer = io.BytesIO()
    torch.save(value, buffer)
    return buffer.getvalue()


@pytest.mark.parametrize(
    "weights, message",
    [(b"", "safe loader"), (b"not a torch file", "safe loader"),
     (_torch_bytes([1, 2]), "weights do not match the config"),
     (_torch_bytes(torch.zeros(3)), "weights do not match the config"),
     (_torch_bytes({}), "weights do not match the config")],
    ids=["empty", "garbage", "list", "tensor", "empty-dict"],
)
def test_weights_that_are_not_a_state_dict(model, tmp_path, weights, message):
    broken = _rewrite(model, tmp_path / "broken.zip", {"actor.pt": weights})
    with pytest.raises(ModelError, match=message):
        load_model(broken)


def _corrupt_member_data(path: Path, member: str) -> None:
    """Overwrite the compressed bytes of ``member`` with 0xFF (an invalid deflate block)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(io.BytesIO(bytes(data))) as zf:
        info = zf.getinfo(member)
    assert info.compress_type == zipfile.ZIP_DEFLATED
    local = info.header_offset
    assert data[local : local + 4] == b"PK\x03\x04"
    name_length = int.from_bytes(data[local + 26 : local + 28], "little")
    extra_length = int.from_bytes(data[local + 28 : local + 30], "little")
    start = local + 30 + name_length + extra_length
    data[start : start + info.compress_size] = b"\xff" * info.compress_size
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("member", ["actor.pt", "config.json"])
def test_corrupt_compressed_member(model, member):
    _corrupt_member_data(model, member)
    with pytest.raises(ModelError, match="not a readable model zip"):
        load_model(model)


def test_deeply_nested_config(model, tmp_path):
    nested = "[" * 100_000 + "]" * 100_000
    broken = _rewrite(model, tmp_path / "nested.zip", {"config.json": nested})
    with pytest.raises(ModelError):
        load_model(broken)


# --- saving -------------------------------------------------------------------------------


def test_save_replaces_an_existing_file_atomically(tmp_path):
    path = tmp_path / "model.zip"
    save_model(path, _actor(seed=0), PRESETS[1], {"seed": 0})
    first = path.read_bytes()
    save_model(path, _actor(seed=1), PRESETS[2], {"seed": 1})
    assert path.read_bytes() != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]
    loaded = load_model(path)
    assert loaded.metadata["seed"] == 1
    assert loaded.env_config == PRESETS[2]
    for original, kept in zip(_actor(seed=1).state_dict().values(),
                              loaded.actor.state_dict().values(), strict=True):
        assert torch.equal(original, kept)


def test_failed_rename_keeps_the_old_file_and_no_temp_file(tmp_path, monkeypatch):
    path = tmp_path / "model.zip"
    save_model(path, _actor(), PRESETS[1], {"seed": 0})
    before = path.read_bytes()

    def refuse(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("rlpgo_gtsam.files.os.replace", refuse)
    with pytest.raises(OutputError, match="cannot write"):
        save_model(path, _actor(seed=1), PRESETS[1], {"seed": 1})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]


def test_unserializable_metadata_keeps_the_old_file(tmp_path):
    path = tmp_path / "model.zip"
    save_model(path, _actor(), PRESETS[1], {"seed": 0})
    before = path.read_bytes()
    with pytest.raises((TypeError, ValueError)):
        save_model(path, _actor(seed=1), PRESETS[1], {"seed": object()})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]


def test_save_into_a_missing_folder(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        save_model(tmp_path / "absent" / "model.zip", _actor(), PRESETS[1], {})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("metadata", [{"format": 99}, {"hidden": 8}], ids=["format", "hidden"])
def test_metadata_cannot_break_reserved_keys(tmp_path, metadata):
    path = tmp_path / "model.zip"
    try:
        save_model(path, _actor(), PRESETS[1], metadata)
    except (ValueError, TypeError):
        return  # refusing reserved keys is also correct
    loaded = load_model(path)
    assert loaded.metadata["format"] == FORMAT_VERSION
    assert loaded.actor.trunk.hidden == HIDDEN


def test_the_width_limit_is_the_one_the_commands_show():
    from rlpgo_gtsam.rl.agent import checkpoint
    from rlpgo_gtsam.rl.models import MAX_HIDDEN

    assert checkpoint._MAX_HIDDEN == MAX_HIDDEN


# --- files that hold options removed in 0.1.0 -------------------------------------------


def _with_env(model: Path, dst: Path, **fields) -> Path:
    config = _config(model)
    config["env"] |= fields
    return _rewrite(model, dst, {"config.json": json.dumps(config)})


def test_removed_env_fields_at_their_off_values_load_as_before(model, tmp_path):
    """Models saved with the options removed in 0.1.0 hold them at their defaults: such a file
    loads, with the same environment and the same actions as one without the fields."""
    from rlpgo_gtsam.rl.agent.checkpoint import REMOVED_ENV_FIELDS

    assert REMOVED_ENV_FIELDS == {"observation": "paper", "reward": "oc", "oc_shaping": 0.0,
                                  "keep": "oc", "sigma_r_max": 0.0, "start": "odometry"}
    fields = REMOVED_ENV_FIELDS | {"oc_shaping": 0}  # JSON may hold 0 for 0.0
    old = load_model(_with_env(model, tmp_path / "old.zip", **fields))
    new = load_model(model)
    assert old.env_config == new.env_config == PRESETS[3]
    x = torch.randn(1, 5, 4), torch.zeros(1, 5, 2)
    with torch.no_grad():
        assert torch.equal(old.actor.deterministic(*x)[0], new.actor.deterministic(*x)[0])


@pytest.mark.parametrize("field, value", [
    ("observation", "rich"), ("reward", "chi2"), ("keep", "chi2"), ("start", "certified"),
    ("oc_shaping", 0.1), ("sigma_r_max", 0.6), ("oc_shaping", False), ("observation", None),
])
def test_removed_env_fields_at_other_values_are_refused_with_what_to_do(model, tmp_path,
                                                                        field, value):
    bad = _with_env(model, tmp_path / "bad.zip", **{field: value})
    with pytest.raises(ModelError) as error:
        load_model(bad)
    message = str(error.value)
    assert f"this model was trained with env.{field}=" in message
    assert "removed in rlpgo-gtsam 0.1.0; retrain it" in message
    assert "bad.zip" in message and "\n" not in message
