"""Calibration of the track–soil model from recorded bags (issue 6).

One call, :func:`calibrate` (bag path, method, options) -> :class:`CalibrationResult`,
serves the ``clm calibrate`` command and the ROS calibration service:

- ``impact``: soil impact test -> CLM (or Lysmer/Winkler) soil parameters,
  by the paper's route (Eq. 16/18 sums, Kouroussis et al. 2011, Sec. 4.1)
  refined by bounded nonlinear least squares on all area receptances
  (:mod:`clm_core.calibration.impact`);
- ``receptance``: hammer on the rail -> railpad/ballast/sleeper (and soil)
  parameters (:mod:`clm_core.calibration.receptance`);
- ``passby``: wheel loads and responses -> selected parameters by output
  error through the time-domain engine (:mod:`clm_core.calibration.passby`).

Every fit states its frequency band and error norm, returns 95 % intervals
(:mod:`clm_core.calibration.lsq`) and warns about parameters the data do
not identify. Bags are read with rosbags (:mod:`clm_core.calibration.bagio`,
channel maps :mod:`clm_core.calibration.channels`); outputs are written by
:func:`clm_core.outputs.calibration_report.write_outputs`; synthetic bags with known parameters come from
:mod:`clm_core.synthetic`. Format and usage: docs/calibration.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from clm_core.lazy import lazy_getattr

if TYPE_CHECKING:
    from clm_core.calibration.api import CalibrationResult, calibrate
    from clm_core.calibration.bagio import BagContents, WheelLoadRecord, read_bag
    from clm_core.calibration.channels import ChannelMap, ChannelSpec, load_channel_map, parse_channel_map
    from clm_core.calibration.errors import BagError, CalibrationError
    from clm_core.calibration.impact import SoilFit, fit_impact
    from clm_core.calibration.lsq import FitResult, FitStats, ParameterEstimate
    from clm_core.calibration.options import CalibrationOptions
    from clm_core.calibration.passby import fit_passby
    from clm_core.calibration.receptance import TrackFit, fit_receptance
    from clm_core.calibration.signals import Recording, SamplingRules, Signal
    from clm_core.calibration.spectra import TransferData, WindowSpec, transfer_functions

#: Public name -> defining module, imported on first use: importing one submodule (``options``) or the
#: package stays light (no scipy.signal, no matplotlib).
_LAZY = {
    "BagContents": "bagio",
    "BagError": "errors",
    "CalibrationError": "errors",
    "CalibrationOptions": "options",
    "CalibrationResult": "api",
    "ChannelMap": "channels",
    "ChannelSpec": "channels",
    "FitResult": "lsq",
    "FitStats": "lsq",
    "ParameterEstimate": "lsq",
    "Recording": "signals",
    "SamplingRules": "signals",
    "Signal": "signals",
    "SoilFit": "impact",
    "TrackFit": "receptance",
    "TransferData": "spectra",
    "WheelLoadRecord": "bagio",
    "WindowSpec": "spectra",
    "calibrate": "api",
    "fit_impact": "impact",
    "fit_passby": "passby",
    "fit_receptance": "receptance",
    "load_channel_map": "channels",
    "parse_channel_map": "channels",
    "read_bag": "bagio",
    "transfer_functions": "spectra",
}


__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = [
    "BagContents",
    "BagError",
    "CalibrationError",
    "CalibrationOptions",
    "CalibrationResult",
    "ChannelMap",
    "ChannelSpec",
    "FitResult",
    "FitStats",
    "ParameterEstimate",
    "Recording",
    "SamplingRules",
    "Signal",
    "SoilFit",
    "TrackFit",
    "TransferData",
    "WheelLoadRecord",
    "WindowSpec",
    "calibrate",
    "fit_impact",
    "fit_passby",
    "fit_receptance",
    "load_channel_map",
    "parse_channel_map",
    "read_bag",
    "transfer_functions",
]
