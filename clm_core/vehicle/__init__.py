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
run
    The typed vehicle-run builder (:class:`VehicleRunSpec` -> simulation) of ``clm simulate
    --vehicle`` and the vehicle node.
reference_track
    A fixed-window reference engine with the streaming engine's coupling API.

Conventions: SI units; displacements and forces positive downwards; the track
is ONE rail line, so vehicle loads are wheel loads (half the axle load).

The names below are imported on first use, so that importing the package (or
reading its presets) does not compile the numba kernels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from clm_core.lazy import lazy_getattr

if TYPE_CHECKING:
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
    from clm_core.vehicle.run import VehicleRunSpec, build_vehicle_run

#: Public name -> defining module (imported on first use: importing the package stays light).
_LAZY = {
    **dict.fromkeys(("hertz_constant", "solve_contact"), "contact"),
    **dict.fromkeys(("CoupledResult", "CoupledSimulation", "simulate"), "coupled"),
    **dict.fromkeys(("DippedJoint", "Irregularity", "JointStep", "Profile", "WheelFlat", "load_profile_csv",
                     "local_stiffness_change", "psd", "random_profile"), "irregularity"),
    **dict.fromkeys(("CarSpec", "Train", "VehicleNewmark", "VehicleType", "build_train"), "multibody"),
    **dict.fromkeys(("VehicleFile", "list_vehicle_presets", "load_vehicle"), "presets"),
    **dict.fromkeys(("VehicleRunSpec", "build_vehicle_run"), "run"),
}


__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = [
    "CarSpec",
    "CoupledResult",
    "CoupledSimulation",
    "DippedJoint",
    "Irregularity",
    "JointStep",
    "Profile",
    "Train",
    "VehicleFile",
    "VehicleNewmark",
    "VehicleRunSpec",
    "VehicleType",
    "WheelFlat",
    "build_train",
    "build_vehicle_run",
    "hertz_constant",
    "list_vehicle_presets",
    "load_profile_csv",
    "load_vehicle",
    "local_stiffness_change",
    "psd",
    "random_profile",
    "simulate",
    "solve_contact",
]
