"""``clm report``: the frequency-domain report of every preset.

The receptance of every track on every soil preset (rigid, Lysmer, CLM) and
the CLM soil chain of every soil, written to ``--out`` with an
``index.json`` of the resonance peaks and delays. Part of ``scripts/demo.sh``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from clm_core.params import list_presets


def register(sub: Any) -> None:
    """Add the ``report`` sub-command."""
    p = sub.add_parser("report", help="frequency-domain report of every track and soil preset")
    p.add_argument("--out", default="results/report", help="output directory (default results/report)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write every receptance and soil-chain report; return the exit code."""
    from clm_core.cli import main as clm

    out = Path(args.out)
    index: dict[str, object] = {}
    for track in list_presets("tracks"):
        for soil in list_presets("soils"):
            for model in ("rigid", "lysmer", "clm"):
                if model == "rigid" and soil != list_presets("soils")[0]:
                    continue
                name = f"receptance_{track}_{'rigid' if model == 'rigid' else soil}_{model}"
                code = clm(["receptance", "--track", track, "--soil", soil, "--model", model, "--out", str(out / name)])
                if code:
                    return code
                index[name] = json.loads((out / name / "summary.json").read_text())["peaks_hz"]
    for soil in list_presets("soils"):
        name = f"soil-chain_{soil}"
        code = clm(["soil-chain", "--soil", soil, "--out", str(out / name)])
        if code:
            return code
        s = json.loads((out / name / "summary.json").read_text())
        index[name] = {
            "measured_delay_s": s["measured_delay_s"],
            "eq21_delay_s": s["eq21_delay_s"],
            "eq23_delay_s": s["eq23_delay_s"],
        }
    (out / "index.json").write_text(json.dumps(index, indent=2) + "\n")
    print(f"report: {len(index)} reports in {out}/ (index.json lists the peaks and delays)")
    return 0
