"""``clm report``: the frequency-domain report of every preset.

The receptance of every track on every soil preset (rigid, Lysmer, CLM) and
the CLM soil chain of every soil (Eq. 21 with the sleeper spacing of the track
the soil preset names: 0.72 m for the Sec. 5.2 soils), written to ``--out``
with an ``index.json`` of the resonance peaks and delays and an ``index.html``
linking every figure and summary (:mod:`clm_core.outputs.report_index`). Part of
``scripts/demo.sh``.
The reports are computed by the same functions as ``clm receptance`` and
``clm soil-chain`` (:func:`~clm_core.commands.receptance.receptance_report`,
:func:`~clm_core.commands.soil_chain.soil_chain_report`), called directly.
"""

from __future__ import annotations

import argparse
from typing import Any, cast

from clm_core.commands._common import add_command, output_dir
from clm_core.commands._options import add_overwrite


def register(sub: Any) -> None:
    """Add the ``report`` sub-command."""
    p = add_command(sub, "report", run)
    p.add_argument("--out", default="results/report", help="output directory (default results/report)")
    add_overwrite(p)


def run(args: argparse.Namespace) -> int:
    """Frequency-domain report of every track and soil preset.

    Receptances H11..H51 of every track preset on every soil preset (rigid ground, Lysmer and CLM soils) and the CLM
    soil chain of every soil (Eq. 16/18 sums, pulse response, delays), each in its own directory under --out, with
    index.json listing the resonance peaks and the delays.
    """
    from clm_core.commands.receptance import receptance_report
    from clm_core.commands.soil_chain import eq21_geometry, shear_wave_speed, soil_chain_report, soil_from_args
    from clm_core.io.files import write_json
    from clm_core.outputs.report_index import write_index
    from clm_core.params import SoilModel, list_presets, load_model, soil_track
    from clm_core.progress import Progress

    tracks, soils = list_presets("tracks"), list_presets("soils")
    jobs = [(track, soil, model) for track in tracks for soil in soils for model in ("rigid", "lysmer", "clm")
            if not (model == "rigid" and soil != soils[0])]
    index: dict[str, object] = {}
    with output_dir(args.out, args.overwrite) as out, Progress(len(jobs) + len(soils), "clm report",
                                                               unit="report") as bar:
        for track, soil, model in jobs:
            name = f"receptance_{track}_{'rigid' if model == 'rigid' else soil}_{model}"
            bar.stage(name)
            (out / name).mkdir(exist_ok=True)
            s = receptance_report(load_model(track, soil, cast(SoilModel, model)), out / name)
            index[name] = s["peaks_hz"]
            bar.update()
        for soil in soils:
            name = f"soil-chain_{soil}"
            bar.stage(name)
            (out / name).mkdir(exist_ok=True)
            # Eq. (21) with the spacing of the track this soil goes with (0.72 m for the Sec. 5.2 soils)
            spacing, width, src = eq21_geometry(soil_track(soil))
            s = soil_chain_report(soil_from_args(soil, "clm", []), out / name, cs=shear_wave_speed(soil), name=soil,
                                  spacing=spacing, width=width, eq21_from=src)
            index[name] = {k: s[k] for k in ("measured_delay_s", "eq21_delay_s", "eq21_inputs", "eq23_delay_s")}
            bar.update()
        write_json(out / "index.json", index)
        html = write_index(out, title="clm report: receptances and soil chains of every preset")
    print(f"report: {len(index)} reports in {out}/ (index.json lists the peaks and delays; {html.name} links "
          "every figure and summary)")
    return 0
