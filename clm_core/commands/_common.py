"""Arguments and helpers shared by the ``clm`` sub-commands."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.params import SOIL_MODELS, ModelParams, load_model, load_params_file, parse_assignments


def add_model_arguments(p: argparse.ArgumentParser, sleepers_default: int) -> None:
    """--track, --soil, --model, --params, --set, --sleepers, --elements-per-bay."""
    p.add_argument("--track", default="mevergnies", help="track preset or YAML file (default: mevergnies)")
    p.add_argument("--soil", default="mevergnies", help="soil preset or YAML file (default: mevergnies)")
    p.add_argument("--model", default="clm", choices=SOIL_MODELS, help="foundation model (default: clm)")
    p.add_argument(
        "--params",
        default=None,
        help="full parameter file (rail, track, soil, overrides); replaces --track/--soil/--model",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter, e.g. --set kb=50e6 (repeatable)",
    )
    p.add_argument(
        "--sleepers", type=int, default=sleepers_default, help=f"number of sleepers (default: {sleepers_default})"
    )
    p.add_argument("--elements-per-bay", type=int, default=2, help="rail elements per sleeper bay (default: 2)")


def model_from_args(args: argparse.Namespace) -> ModelParams:
    """Build the validated parameter set the arguments describe."""
    sets = parse_assignments(args.set)
    if args.params:
        mp = load_params_file(args.params)
        return mp.override(**sets) if sets else mp
    return load_model(args.track, args.soil, args.model, sets)


def out_dir(path: str) -> Path:
    """Create and return the output directory."""
    d = Path(path)
    d.mkdir(parents=True, exist_ok=True)
    return d


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as indented JSON (numpy values converted)."""
    path.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n")
