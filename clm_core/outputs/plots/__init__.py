"""Every matplotlib figure of the suite: PNG files an engineer can put in a report.

This package is the only place in :mod:`clm_core` that imports matplotlib.
Import it inside the function that draws (never at module level elsewhere),
so that importing the core stays light and never touches matplotlib. No pyplot is
used: figures are :class:`matplotlib.figure.Figure` objects drawn by their
own Agg canvas, so a user's backend and pyplot state are left alone.

Figures (file, function, command that writes it):

==============================  =============================  ==========================
``receptance.png``              :func:`plot_receptance`        ``clm receptance``, ``clm report``
``chain.png``                   :func:`plot_chain`             ``clm soil-chain``, ``clm report``
``simulate.png``                :func:`plot_run`               ``clm simulate`` (moving loads)
``soil_forces.png``,            :func:`plot_run_report`        ``clm simulate`` (moving loads)
``spectra.png``,
``third_octave.png``
``wheel_loads.png``,            :func:`plot_vehicle_run`       ``clm simulate --vehicle``
``soil_forces.png``,
``spectra.png``,
``third_octave.png``
``sleeper_soil_forces.png``,    :func:`plot_demo`              ``clm demo``
``rail_deflection.png``,
``wheel_loads.png``,
``soil_forces.png``,
``spectra.png``,
``third_octave.png``
``transfer_functions.png``,     :func:`plot_calibration`       ``clm calibrate``
``sums.png``,
``time_histories.png``
``sums.png``,                   :func:`plot_soil_calibration`  ``clm soil-calibrate``
``receptances.png``
``critical_speed.png``,         :func:`plot_study`             ``clm study``
``exceedance.png``
==============================  =============================  ==========================

Rules every figure follows (and the tests check on every figure the suite
renders, through :data:`figure_observers`): each axis has a label with its
unit in brackets; a legend covers no extreme of any curve and no peak label
(after the layout, a legend that would is moved to a free corner, or given
headroom above the curves, or put outside the axes); wheel loads get one panel per wheel; curves
that lie on each other are told apart by dashes, markers and drawing order.
"""

from clm_core.outputs.plots._base import MAX_WHEEL_PANELS, figure_observers
from clm_core.outputs.plots.calibration import plot_calibration, plot_soil_calibration
from clm_core.outputs.plots.frequency import plot_chain, plot_receptance
from clm_core.outputs.plots.runs import (
    DEMO_FIGURES,
    RUN_FIGURES,
    VEHICLE_FIGURES,
    plot_demo,
    plot_run,
    plot_run_report,
    plot_vehicle_run,
)
from clm_core.outputs.plots.studies import plot_critical_speed, plot_exceedance, plot_study

__all__ = [
    "DEMO_FIGURES",
    "MAX_WHEEL_PANELS",
    "RUN_FIGURES",
    "VEHICLE_FIGURES",
    "figure_observers",
    "plot_calibration",
    "plot_chain",
    "plot_critical_speed",
    "plot_demo",
    "plot_exceedance",
    "plot_receptance",
    "plot_run",
    "plot_run_report",
    "plot_soil_calibration",
    "plot_study",
    "plot_vehicle_run",
]
