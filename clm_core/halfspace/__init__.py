"""Rigorous half-space reference for the CLM soil model.

Surface Green's functions of a horizontally layered viscoelastic half-space
(vertical load, vertical displacement; :mod:`.green`), boundary elements for
rows of rigid rectangular contact areas (:mod:`.bem`), CLM calibration from a
soil profile (:mod:`.calibrate`) and reference impact histories
(:mod:`.impact`). Soil profiles are read by :mod:`.profile`.

Conventions: SI units; time dependence exp(+i w t); z, forces and
displacements positive downwards; material damping E* = E (1 + i w beta + 2 i xi).
"""

from clm_core.halfspace.bem import RowGeometry, RowModel, RowResult, disk_impedance, row_sweep
from clm_core.halfspace.calibrate import SoilCalibration, auto_geometry, calibrate_profile
from clm_core.halfspace.green import KernelEngine, RadialKernel, point_load_displacement, surface_flexibility_k
from clm_core.halfspace.impact import ImpactResponse, impact_response, save_impact_npz
from clm_core.profile import Layer, SoilProfile, load_profile

__all__ = [
    "ImpactResponse",
    "KernelEngine",
    "Layer",
    "RadialKernel",
    "RowGeometry",
    "RowModel",
    "RowResult",
    "SoilCalibration",
    "SoilProfile",
    "auto_geometry",
    "calibrate_profile",
    "disk_impedance",
    "impact_response",
    "load_profile",
    "point_load_displacement",
    "row_sweep",
    "save_impact_npz",
    "surface_flexibility_k",
]
