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
import zipfile
import zlib
from dataclasses import asdict
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import torch

from rlpgo_gtsam.agent.networks import Actor
from rlpgo_gtsam.episode import EnvConfig
from rlpgo_gtsam.errors import ModelError
from rlpgo_gtsam.files import write_bytes

__all__ = ["FORMAT_VERSION", "save_model", "load_model", "LoadedModel"]

FORMAT_VERSION = 1
_CONFIG, _WEIGHTS = "config.json", "actor.pt"
_RESERVED = ("format", "package_version", "torch_version", "hidden", "env")
_MAX_HIDDEN = 4096
# Caps on the uncompressed members (a 4096-unit actor's weights are about 540 MB in float32;
# the shipped ones are 0.2 MB): checked before reading, and the read itself is bounded, so a
# zip bomb or a lying header cannot inflate memory.
_MAX_CONFIG_BYTES = 1 << 20
_MAX_WEIGHTS_BYTES = 1 << 30


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


def save_model(path: str | os.PathLike[str], actor: Actor, env_config: EnvConfig,
               metadata: dict) -> None:
    """Write a model zip atomically; ``metadata`` must be JSON-serializable."""
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
    write_bytes(path, archive.getvalue())


# The schema of config.json's "env" (EnvConfig): type and inclusive range of every field.
_ENV_SCHEMA = {
    "n": (int, 2, 10_000_000), "sigma_r": (float, 0.0, 3.2), "sigma_t": (float, 0.0, 1e6),
    "d": (float, 0.0, 1e6), "lc": (float, 0.0, 1.0), "cycles": (int, 1, 10_000),
    "action_range_rad": (float, 0.0, 3.2), "noisy_measurements": (bool, None, None),
}
_MAX_CYCLES = 10_000


def _check_number(path: Path, name: str, value, kind: type, low, high) -> None:
    """Raise ModelError unless ``value`` is a ``kind`` within [low, high] (finite)."""
    if kind is bool:
        if type(value) is not bool:
            raise ModelError(f"{path}: config field {name} must be true or false")
        return
    allowed = (int,) if kind is int else (int, float)
    if type(value) not in allowed or (kind is float and not math.isfinite(value)) or \
            not low <= value <= high:
        shown = repr(value)
        shown = shown if len(shown) <= 40 else shown[:40] + "..."
        raise ModelError(f"{path}: config field {name} must be a {kind.__name__} in "
                         f"[{low:g}, {high:g}], got {shown}")


def _env_config(path: Path, env) -> EnvConfig:
    if not isinstance(env, dict):
        raise ModelError(f"{path}: config field env must be an object")
    unknown = sorted(set(env) - set(_ENV_SCHEMA))
    if unknown:
        raise ModelError(f"{path}: unknown env field(s) {', '.join(unknown)[:200]}")
    for name, value in env.items():
        _check_number(path, f"env.{name}", value, *_ENV_SCHEMA[name])
    return EnvConfig(**env)


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

    Raises:
        ModelError: missing file, not a zip, no config or weights, another format
            version, or weights that do not fit the network the config describes.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            if _CONFIG not in names or _WEIGHTS not in names:
                raise ModelError(f"{path}: not an rlpgo model (needs {_CONFIG} and {_WEIGHTS})")
            config = json.loads(_read_bounded(zf, _CONFIG, _MAX_CONFIG_BYTES, path))
            weights = _read_bounded(zf, _WEIGHTS, _MAX_WEIGHTS_BYTES, path)
    except (zipfile.BadZipFile, EOFError, OSError, zlib.error, NotImplementedError,
            RuntimeError) as error:  # RuntimeError: an encrypted member
        first = " ".join(str(error).split())[:200]
        raise ModelError(f"{path}: not a readable model zip ({first})") from None
    except (ValueError, RecursionError):  # JSONDecodeError, bad UTF-8, a 5000-digit integer
        raise ModelError(f"{path}: {_CONFIG} is not valid JSON (or holds an absurd number)") \
            from None
    if not isinstance(config, dict):
        raise ModelError(f"{path}: {_CONFIG} is not a JSON object")
    if type(config.get("format")) is not int or config["format"] != FORMAT_VERSION:
        raise ModelError(
            f"{path}: format {config.get('format')}, this version reads format "
            f"{FORMAT_VERSION}; use a matching rlpgo-gtsam"
        )
    try:
        state = torch.load(io.BytesIO(weights), weights_only=True, map_location="cpu")
    except Exception as error:  # torch raises UnpicklingError, RuntimeError, ...
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ModelError(f"{path}: weights refused by the safe loader: {first}") from None
    hidden = config.get("hidden")
    if type(hidden) is not int or not 1 <= hidden <= _MAX_HIDDEN:
        raise ModelError(f"{path}: hidden size must be an integer in 1..{_MAX_HIDDEN}, "
                         f"got {hidden!r}")
    fc = state.get("trunk.fc.weight") if isinstance(state, dict) else None
    if not isinstance(fc, torch.Tensor) or fc.shape[0] != hidden:
        raise ModelError(f"{path}: weights do not match the config (hidden {hidden})")
    env_config = _env_config(path, config.get("env"))
    _check_number(path, "test_cycles", config.get("test_cycles", 1), int, 1, _MAX_CYCLES)
    try:
        actor = Actor(hidden)
        actor.load_state_dict(state, strict=True)
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        first = str(error).strip().splitlines()[0]
        raise ModelError(f"{path}: weights do not match the config: {first}") from None
    if not all(bool(torch.isfinite(tensor).all()) for tensor in actor.state_dict().values()):
        raise ModelError(f"{path}: the weights hold NaN or infinite values")
    actor.eval()
    return LoadedModel(actor, env_config, config, path)
