"""Helpers shared by the benchmark scripts: where the data lies, how results are written."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import gtsam
import torch

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATASETS = Path(os.environ.get("RLPGO_DATASETS", ROOT.parent / "shared" / "datasets"))


def machine() -> dict:
    """What the numbers were measured on."""
    return {
        "python": platform.python_version(),
        "gtsam": getattr(gtsam, "__version__", "4.3.0"),
        "torch": torch.__version__,
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
    }


def write_result(name: str, data: dict) -> Path:
    """Write ``benchmarks/results/<name>.json`` and return its path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({"machine": machine(), **data}, indent=2) + "\n")
    return path


def write_rows(name: str, command: str, rows: list[dict], table: str) -> None:
    """Checkpoint a benchmark's rows: ``benchmarks/results/<name>.json`` (the command that made
    them and the rows so far) and its table, ``<name>.md``."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps({"command": command, "rows": rows},
                                                     indent=1) + "\n")
    (RESULTS / f"{name}.md").write_text(table)
