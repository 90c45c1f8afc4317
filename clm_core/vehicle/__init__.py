"""Vehicle–track coupling: multibody vehicles, Hertzian contact, irregularities, presets.

Modules
-------
multibody
    Vertical multibody vehicles (car body, bogies, wheelsets, primary and
    secondary suspensions), trains and articulated trainsets, on one rail line.
contact
    Hertz contact constant and law; per-step Newton solution of the contact forces.
irregularity
    Random profiles from FRA / German PSDs, CSV profiles, dipped joints, joint
    steps, wheel flats, local track stiffness changes.
coupled
    The monolithic vehicle–track time integration on the streaming track engine.
presets
    YAML vehicle presets (``clm_core/presets/vehicles``) and user vehicle files.
impact
    Jenkins et al. (1974) P2 force and equivalent track parameters.
cli_support
    ``--vehicle`` options and the run/write function for ``clm simulate``.
reference_track
    A fixed-window reference engine with the streaming engine's coupling API.

Conventions: SI units; displacements and forces positive downwards; the track
is ONE rail line, so vehicle loads are wheel loads (half the axle load).
"""

from clm_core.vehicle.contact import hertz_constant, solve_contact
from clm_core.vehicle.coupled import CoupledResult, CoupledSimulation, simulate
from clm_core.vehicle.irregularity import (
    DippedJoint,
    Irregularity,
    JointStep,
    Profile,
    WheelFlat,
    load_profile_csv,
    local_stiffness_change,
    psd,
    random_profile,
)
from clm_core.vehicle.multibody import CarSpec, Train, VehicleNewmark, VehicleType, build_train
from clm_core.vehicle.presets import VehicleFile, list_vehicle_presets, load_vehicle

__all__ = [
    "CarSpec", "CoupledResult", "CoupledSimulation", "DippedJoint", "Irregularity", "JointStep",
    "Profile", "Train", "VehicleFile", "VehicleNewmark", "VehicleType", "WheelFlat", "build_train",
    "hertz_constant", "list_vehicle_presets", "load_profile_csv", "load_vehicle",
    "local_stiffness_change", "psd", "random_profile", "simulate", "solve_contact",
]
