"""Writing the CLIs' JSON outputs atomically."""

from __future__ import annotations

import json
import os

from rlpgo_gtsam.files import write_text


def write_json(path: str | os.PathLike[str], data: object) -> None:
    """Write ``data`` as indented JSON to ``path``, atomically."""
    write_text(path, json.dumps(data, indent=2) + "\n")
