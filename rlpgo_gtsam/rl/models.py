"""Finding shipped models by name, in a checkout (``models/``) or an installed wheel."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from rlpgo_gtsam.errors import ModelError

if TYPE_CHECKING:  # loading a model needs torch; naming one does not
    from rlpgo_gtsam.rl.agent.checkpoint import LoadedModel

__all__ = ["models_dir", "resolve_model", "shipped_models", "DEFAULT_MODEL",
           "DEFAULT_PRESET_MODEL", "MAX_HIDDEN"]

DEFAULT_MODEL = "preset4"
DEFAULT_PRESET_MODEL = "preset{preset}"
# The widest network a model file may hold (the paper's is 512): a 1024-wide actor's weights
# are 44 MiB, so loading any accepted model stays around 100 MB. rlpgo-train takes no wider.
MAX_HIDDEN = 1024


def models_dir() -> Path:
    """``rlpgo_gtsam/_models`` in a wheel, else the checkout's top-level ``models/``."""
    package = Path(__file__).resolve().parents[1]
    packaged = package / "_models"
    return packaged if packaged.is_dir() else package.parent / "models"


def shipped_models() -> list[str]:
    """Names of the shipped models."""
    folder = models_dir()
    return sorted(p.stem for p in folder.glob("*.zip")) if folder.is_dir() else []


def model_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The file a model name or path refers to (a shipped name must exist)."""
    candidate = Path(name_or_path)
    # A bare name is always a shipped model: a same-named file or folder in the working
    # directory is never taken for it.
    if candidate.suffix == ".zip" or os.sep in str(name_or_path) or (
            os.altsep is not None and os.altsep in str(name_or_path)):
        return candidate
    path = models_dir() / f"{name_or_path}.zip"
    if not path.exists():
        known = ", ".join(shipped_models()) or "none"
        raise ModelError(f"no shipped model named '{name_or_path}' (shipped: {known})")
    return path


def resolve_model(name_or_path: str | os.PathLike[str]) -> LoadedModel:
    """Load a shipped model by name (``preset1``) or any model file by path."""
    from rlpgo_gtsam.rl.agent.checkpoint import load_model

    return load_model(model_path(name_or_path))
