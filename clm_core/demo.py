"""The suite's end-to-end demo on shipped defaults (``scripts/demo.sh``).

Frequency-domain report: the receptance of every track on every soil preset
and model, and the CLM soil chain of every soil, written to ``results/``
with a ``results/index.json`` of the resonance peaks.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from clm_core.cli import main as clm
from clm_core.params import list_presets


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; return the exit code."""
    ap = argparse.ArgumentParser(prog="clm-demo", description=__doc__)
    ap.add_argument("--out", default="results", help="output directory (default results/)")
    args = ap.parse_args(argv)
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
    print(f"demo: {len(index)} reports in {out}/ (index.json lists the peaks and delays)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
