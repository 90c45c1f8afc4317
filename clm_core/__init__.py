"""clm_core: coupled lumped mass (CLM) railway track–soil dynamics.

The numerical core of the suite (no ROS imports): foundation models, track
assembly, receptances, time integration, vehicle, calibration and plots, after
Kouroussis, Gazetas, Anastasopoulos, Conti & Verlinden (2011), "Discrete
modelling of vertical track–soil coupling for vehicle–track dynamics", Soil
Dyn. Earthq. Eng. 31(12):1711–1723.

Conventions: SI units (N, m, s, kg); displacements and forces positive
downwards (spring compression positive).
"""

__version__ = "0.1.0"
