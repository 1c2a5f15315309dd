"""Model files: a zip of ``config.json`` and the actor's ``state_dict``, never a pickle.

A shipped model holds what inference needs (actor with its encoder) and metadata: format
version, package and torch versions, network size, environment, training command, seed,
episodes, evaluation figures. Weights load with ``torch.load(..., weights_only=True)``,
so a model file cannot run code. Critics and optimizer state go to a separate training
checkpoint (``*.train.pt``), not shipped.
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
import zipfile
import zlib
from dataclasses import asdict
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import torch

from rlpgo_gtsam.errors import ModelError
from rlpgo_gtsam.files import write_bytes
from rlpgo_gtsam.rl.agent.networks import Actor
from rlpgo_gtsam.rl.episode import EnvConfig

__all__ = ["FORMAT_VERSION", "REMOVED_ENV_FIELDS", "save_model", "model_bytes", "load_model",
           "LoadedModel", "check_env_config"]

FORMAT_VERSION = 1
_CONFIG, _WEIGHTS = "config.json", "actor.pt"
_RESERVED = ("format", "package_version", "torch_version", "hidden", "env")
# The widest actor a model may hold (rlpgo_gtsam.rl.models.MAX_HIDDEN, which the commands
# import without torch; models sits above this module, and a test checks they agree).
_MAX_HIDDEN = 1024
# Caps on the uncompressed members, checked against the zip header before reading and
# enforced by a bounded read (a zip bomb or a lying header cannot inflate memory). The
# weights are further capped at what an actor of the config's hidden size needs.
_MAX_CONFIG_BYTES = 1 << 20
_MAX_WEIGHTS_BYTES = 64 << 20
_WEIGHTS_FRAMING = 1 << 20  # torch.save's zip and pickle framing around the tensors


def package_version() -> str:
    """The installed rlpgo-gtsam's version (``unknown`` when run from a bare checkout)."""
    try:
        return version("rlpgo-gtsam")
    except PackageNotFoundError:
        return "unknown"


class LoadedModel:
    """An actor ready for inference, its environment config and its metadata."""

    def __init__(self, actor: Actor, env_config: EnvConfig, metadata: dict, path: Path) -> None:
        self.actor = actor
        self.env_config = env_config
        self.metadata = metadata
        self.path = path


def model_bytes(actor: Actor, env_config: EnvConfig, metadata: dict) -> bytes:
    """The bytes of a model zip (what :func:`save_model` writes); ``metadata`` must be
    JSON-serializable and may not set the keys the package writes itself."""
    reserved = set(metadata) & set(_RESERVED)
    if reserved:
        raise ValueError(f"metadata may not set {', '.join(sorted(reserved))}")
    config = {
        "format": FORMAT_VERSION,
        "package_version": package_version(),
        "torch_version": torch.__version__,
        "hidden": actor.trunk.hidden,
        "env": asdict(env_config),
        **metadata,
    }
    weights = io.BytesIO()
    torch.save(actor.state_dict(), weights)
    archive = io.BytesIO()
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(_CONFIG, json.dumps(config, indent=2))
        zf.writestr(_WEIGHTS, weights.getvalue())
    return archive.getvalue()


def save_model(path: str | os.PathLike[str], actor: Actor, env_config: EnvConfig,
               metadata: dict) -> None:
    """Write a model zip atomically; ``metadata`` must be JSON-serializable."""
    write_bytes(path, model_bytes(actor, env_config, metadata))


# The schema of config.json: type and inclusive range of every field the package reads or
# writes. "env" (EnvConfig) is an object of its own; other top-level keys are free metadata
# (save_model's ``metadata``), kept but never read.
_MAX_CYCLES = 10_000
_ENV_SCHEMA = {
    "n": (int, 2, 1_000_000), "sigma_r": (float, 0.0, 3.2), "sigma_t": (float, 0.0, 1e6),
    "d": (float, 0.0, 1e6), "lc": (float, 0.0, 1.0), "cycles": (int, 1, _MAX_CYCLES),
    "action_range_rad": (float, 0.0, 3.2), "noisy_measurements": (bool, None, None),
}
# Environment options removed in 0.1.0 (no shipped model uses them), and the value that
# meant "off". Files written while they existed hold them: a file with a field at this value
# loads as before; any other value needs the removed code, and is refused.
REMOVED_ENV_FIELDS = {"observation": "paper", "reward": "oc", "oc_shaping": 0.0, "keep": "oc",
                      "sigma_r_max": 0.0, "start": "odometry"}
_REMOVED_IN = "0.1.0"
_TOP_SCHEMA = {
    "format": (int, 0, 1_000_000), "hidden": (int, 1, _MAX_HIDDEN),
    "test_cycles": (int, 1, _MAX_CYCLES), "preset": (int, 1, 5), "seed": (int, 0, 2**64 - 1),
    "episodes": (int, 0, 10**9), "selected_episode": (int, 0, 10**9),
    "train_seconds": (float, 0.0, 1e12), "validation_best_oc_ratio": (float, 0.0, 1e12),
    "package_version": (str, 0, 200), "torch_version": (str, 0, 200),
    "command": (str, 0, 100_000),
}
_REQUIRED = ("format", "hidden", "env")


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:40] + "..."


def _check_field(path: Path, name: str, value, kind: type, low, high) -> None:
    """Raise ModelError unless ``value`` is a ``kind`` within [low, high] (numbers finite;
    for a string, [low, high] bounds its length)."""
    if kind is bool:
        if type(value) is not bool:
            raise ModelError(f"{path}: config field {name} must be true or false, "
                             f"got {_shown(value)}")
        return
    if kind is str:
        if type(value) is not str or not low <= len(value) <= high:
            raise ModelError(f"{path}: config field {name} must be a string of at most "
                             f"{high} characters, got {_shown(value)}")
        return
    allowed = (int,) if kind is int else (int, float)
    if type(value) not in allowed or (kind is float and not math.isfinite(value)) or \
            not low <= value <= high:
        what = "an integer" if kind is int else "a finite number"
        raise ModelError(f"{path}: config field {name} must be {what} in "
                         f"[{low:g}, {high:g}], got {_shown(value)}")


def _check_config(path: Path, config: dict) -> EnvConfig:
    """Every known field of ``config`` against the schema; returns its EnvConfig."""
    if type(config.get("format")) is not int or config["format"] != FORMAT_VERSION:
        raise ModelError(
            f"{path}: format {_shown(config.get('format'))}, this version reads format "
            f"{FORMAT_VERSION}; use a matching rlpgo-gtsam"
        )
    hidden = config.get("hidden")
    if type(hidden) is not int or not 1 <= hidden <= _MAX_HIDDEN:
        raise ModelError(f"{path}: hidden size must be an integer in 1..{_MAX_HIDDEN}, "
                         f"got {_shown(hidden)}")
    for name, value in config.items():
        if name in _TOP_SCHEMA:
            _check_field(path, name, value, *_TOP_SCHEMA[name])
        elif name in _ENV_SCHEMA:
            raise ModelError(f"{path}: config field {name} belongs inside \"env\"")
    sac = config.get("sac", {})
    if not isinstance(sac, dict) or not all(
            type(v) in (int, float, bool) and math.isfinite(v) for v in sac.values()):
        raise ModelError(f"{path}: config field sac must be an object of finite numbers")
    env = config.get("env")
    if not isinstance(env, dict):
        raise ModelError(f"{path}: config field env must be an object")
    known = {}
    for name, value in env.items():
        if name in _ENV_SCHEMA:
            _check_field(path, f"env.{name}", value, *_ENV_SCHEMA[name])
            known[name] = value
        elif name in REMOVED_ENV_FIELDS:
            _check_removed(path, name, value)
        elif name in _TOP_SCHEMA:
            raise ModelError(f"{path}: env field {name} belongs at the top level of {_CONFIG}, "
                             "not inside \"env\"")
        else:
            raise ModelError(f"{path}: unknown env field {_shown(name)} "
                             f"(known: {', '.join(_ENV_SCHEMA)})")
    return EnvConfig(**known)


def _check_removed(path: Path, name: str, value) -> None:
    """Accept a removed env field at its "off" value; refuse any other with what to do."""
    off = REMOVED_ENV_FIELDS[name]
    kinds = (int, float) if type(off) is float else (type(off),)
    if type(value) in kinds and value == off:
        return
    raise ModelError(f"{path}: this model was trained with env.{name}={_shown(value)}, an "
                     f"option removed in rlpgo-gtsam {_REMOVED_IN}; retrain it without it")


def check_env_config(env_config: EnvConfig, path: Path) -> None:
    """Raise ModelError unless ``env_config`` fits the schema a model file must meet (what a
    run would write to ``path``), before any work."""
    _check_config(path, {"format": FORMAT_VERSION, "hidden": 1, "env": asdict(env_config)})


def _weights_limit(hidden: int) -> int:
    """The most bytes a saved actor of width ``hidden`` takes (counted on torch's "meta"
    device, which allocates nothing), capped by :data:`_MAX_WEIGHTS_BYTES`."""
    with torch.device("meta"):
        actor = Actor(hidden)
    tensors = sum(t.numel() * t.element_size() for t in actor.state_dict().values())
    return min(tensors + _WEIGHTS_FRAMING, _MAX_WEIGHTS_BYTES)


def _read_bounded(zf: zipfile.ZipFile, name: str, limit: int, path: Path) -> bytes:
    """A member's bytes, refused if it declares or inflates to more than ``limit`` bytes."""
    if zf.getinfo(name).file_size > limit:
        raise ModelError(f"{path}: member {name} is larger than {limit} bytes uncompressed")
    with zf.open(name) as member:
        data = member.read(limit + 1)
    if len(data) > limit:
        raise ModelError(f"{path}: member {name} is larger than {limit} bytes uncompressed")
    return data


def load_model(path: str | os.PathLike[str]) -> LoadedModel:
    """Load a model zip without unpickling anything.

    The config is read and checked against its schema first; the weights member is then
    read only up to what an actor of the config's width needs, so no file can make this
    allocate more than about 100 MB.

    Raises:
        ModelError: missing file, not a zip (or an encrypted or unknown-compression one),
            no config or weights, another format version, a config field of the wrong type
            or out of range, a removed option at a value other than its "off" one
            (:data:`REMOVED_ENV_FIELDS`), or weights that are not finite or do not fit the
            network the config describes.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            if _CONFIG not in names or _WEIGHTS not in names:
                raise ModelError(f"{path}: not an rlpgo model (needs {_CONFIG} and {_WEIGHTS})")
            try:
                config = json.loads(_read_bounded(zf, _CONFIG, _MAX_CONFIG_BYTES, path))
            except (ValueError, RecursionError):  # bad JSON or UTF-8, a 5000-digit integer
                raise ModelError(f"{path}: {_CONFIG} is not valid JSON (or holds an absurd "
                                 "number)") from None
            if not isinstance(config, dict):
                raise ModelError(f"{path}: {_CONFIG} is not a JSON object")
            env_config = _check_config(path, config)
            hidden = config["hidden"]
            weights = _read_bounded(zf, _WEIGHTS, _weights_limit(hidden), path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, zlib.error,
            NotImplementedError, RuntimeError, ValueError, OverflowError) as error:
        # RuntimeError: an encrypted member; NotImplementedError: an unknown compression
        first = " ".join(str(error).split())[:200] or type(error).__name__
        raise ModelError(f"{path}: not a readable model zip ({first})") from None
    try:
        with warnings.catch_warnings():
            # torch warns of the pickle protocol before refusing: the refusal says it all
            warnings.simplefilter("ignore", UserWarning)
            state = torch.load(io.BytesIO(weights), weights_only=True, map_location="cpu")
    except Exception as error:  # torch raises UnpicklingError, RuntimeError, ...
        # torch's text goes on to suggest turning the safety off: its reason is enough
        reason = " ".join(str(error).split())
        cause = reason.split("WeightsUnpickler error:")[-1].split(".")[0].strip() \
            if "WeightsUnpickler error:" in reason else type(error).__name__
        raise ModelError(f"{path}: weights refused by the safe loader (a model file holds "
                         f"tensors only; this one holds more: {cause[:120]})") from None
    fc = state.get("trunk.fc.weight") if isinstance(state, dict) else None
    if not isinstance(fc, torch.Tensor) or fc.shape[0] != hidden:
        raise ModelError(f"{path}: weights do not match the config (hidden {hidden})")
    try:
        actor = Actor(hidden)
        actor.load_state_dict(state, strict=True)
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        first = " ".join(str(error).split())[:200] or type(error).__name__
        raise ModelError(f"{path}: weights do not match the config: {first}") from None
    if not all(bool(torch.isfinite(tensor).all()) for tensor in actor.state_dict().values()):
        raise ModelError(f"{path}: the weights hold NaN or infinite values")
    actor.eval()
    return LoadedModel(actor, env_config, config, path)
