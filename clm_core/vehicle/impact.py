"""Dipped-joint impact forces: Jenkins et al. (1974) P1/P2 formulas and equivalent track parameters.

Jenkins, Stephenson, Clayton, Morland & Lyon (1974), "The effect of track
and vehicle parameters on wheel/rail vertical dynamic forces", Railway
Engineering Journal 3(1):2–16, give for a wheel crossing a dipped joint of
total angle 2 alpha [rad] at speed V [m/s] (static wheel load P0 [N],
unsprung mass per wheel M_u [kg], Hertz linearised stiffness K_H [N/m],
effective rail mass m_e [kg]; track idealised as a single mass–spring–
damper M_t, K_t, C_t under the wheel):

    P1 = P0 + 2 alpha V sqrt(K_H m_e / (1 + m_e / M_u))

    P2 = P0 + 2 alpha V sqrt(M_u / (M_u + M_t))
              * [1 - C_t pi / (4 sqrt(K_t (M_u + M_t)))] * sqrt(K_t M_u)

(as reproduced e.g. in Esveld 2001, "Modern Railway Track", Sec. 5.6).
P1 (the short peak of the wheel on the rail's contact mass) is given for
reference; P2 is computed here (:func:`jenkins_p2`). The formula belongs to
a continuous, single-degree-of-freedom idea of the track, so the discrete
CLM track must first be reduced to M_t, K_t, C_t:
:func:`equivalent_track` fits K_t - w^2 M_t + j w C_t to the track's point
dynamic stiffness 1 / H(w) (direct receptance of the assembled model) over a
low-frequency band around the P2 resonance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from clm_core.arrays import Array
from clm_core.errors import ParameterError
from clm_core.frequency import dynamic_solve
from clm_core.params import ModelParams
from clm_core.track import assemble


@dataclass(frozen=True)
class EquivalentTrack:
    """Single-DOF equivalent of the track under a wheel (per rail).

    Attributes
    ----------
    Kt : float
        Stiffness [N/m].
    Mt : float
        Mass [kg].
    Ct : float
        Damping [N s/m].
    band : (float, float)
        Fitted frequency band [Hz].
    rel_error : float
        RMS relative misfit of the dynamic stiffness over the band [-].
    """

    Kt: float
    Mt: float
    Ct: float
    band: tuple[float, float]
    rel_error: float

    def p2_frequency(self, Mu: float) -> float:
        """Undamped P2 resonance sqrt(K_t / (M_u + M_t)) / (2 pi) [Hz] for unsprung mass M_u [kg]."""
        return math.sqrt(self.Kt / (Mu + self.Mt)) / (2 * math.pi)


def point_dynamic_stiffness(
    params: ModelParams, f: Array, position: str = "average", n_sleepers: int = 61, elements_per_bay: int = 2
) -> NDArray[np.complex128]:
    """Dynamic stiffness 1/H(f) [N/m] of the rail at the track centre.

    Parameters
    ----------
    params : ModelParams
        The track–soil model.
    f : array_like
        Frequencies [Hz].
    position : {'sleeper', 'midspan', 'average'}
        Load above the central sleeper, at mid-span after it, or the mean of
        the two dynamic stiffnesses (a wheel sees both).
    n_sleepers : int
        Sleepers of the assembled track, centred on the load.
    elements_per_bay : int
        Rail elements per sleeper bay.
    """
    sysm = assemble(params, n_sleepers, elements_per_bay, first_sleeper=-(n_sleepers // 2))
    d = params.track.spacing

    def stiff(x: float) -> NDArray[np.complex128]:
        dofs, w = sysm.point_load(x)
        F = np.zeros(sysm.n_dof)
        np.add.at(F, dofs, w)
        X = dynamic_solve(sysm, f, F)
        return np.asarray(1.0 / (X @ F), dtype=complex)

    if position == "sleeper":
        return stiff(0.0)
    if position == "midspan":
        return stiff(0.5 * d)
    if position == "average":
        return 0.5 * (stiff(0.0) + stiff(0.5 * d))
    raise ParameterError(f"position = {position!r}: one of 'sleeper', 'midspan', 'average'")


def equivalent_track(
    params: ModelParams, Mu: float | None = None, band: tuple[float, float] | None = None,
    position: str = "average", n_sleepers: int = 61,
) -> EquivalentTrack:
    """Fit M_t, K_t, C_t of a single-DOF track to the model's point dynamic stiffness.

    Least squares on Re D = K_t - w^2 M_t and Im D = w C_t over ``band`` [Hz]
    (200 points). Without a band: 1 Hz to twice the P2 frequency of
    unsprung mass ``Mu`` [kg] per wheel (one refinement from a 1–100 Hz fit),
    or 1–100 Hz without ``Mu``.
    """
    def fit(lo: float, hi: float) -> EquivalentTrack:
        f = np.linspace(lo, hi, 200)
        w = 2 * np.pi * f
        D = point_dynamic_stiffness(params, f, position, n_sleepers)
        Ar = np.stack([np.ones_like(w), -(w**2)], axis=1)
        (Kt, Mt), *_ = np.linalg.lstsq(Ar, D.real, rcond=None)
        Ct = float(np.sum(w * D.imag) / np.sum(w**2))
        model = Kt - w**2 * Mt + 1j * w * Ct
        err = float(np.sqrt(np.mean(np.abs(model - D) ** 2 / np.abs(D) ** 2)))
        return EquivalentTrack(float(Kt), float(Mt), Ct, (lo, hi), err)

    if band is not None:
        lo, hi = float(band[0]), float(band[1])
        if not (0 < lo < hi):
            raise ParameterError(f"band = {band}: need 0 < f_lo < f_hi [Hz]")
        return fit(lo, hi)
    eq = fit(1.0, 100.0)
    if Mu is None:
        return eq
    return fit(1.0, 2.0 * eq.p2_frequency(Mu))


def jenkins_p2(P0: float, two_alpha: float, V: float, Mu: float, track: EquivalentTrack) -> float:
    """Jenkins et al. (1974) P2 force [N] (module docstring)."""
    Kt, Mt, Ct = track.Kt, track.Mt, track.Ct
    return float(
        P0 + two_alpha * V * math.sqrt(Mu / (Mu + Mt))
        * (1.0 - Ct * math.pi / (4.0 * math.sqrt(Kt * (Mu + Mt)))) * math.sqrt(Kt * Mu)
    )

