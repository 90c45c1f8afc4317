"""Validation (c): the two-step transfer vs the coupled half-space BEM at one frequency (issue 23.3).

The BEM (clm_core.halfspace.bem) solves the row of rigid massless contact
areas with their through-soil coupling; the two-step method loads the free
surface with a uniform pressure on one area and reads the displacement of
the others as the mean free-field displacement over them, ignoring the
coupling. H[a, b] (area a's displacement per unit force on area b) of both
must agree where the areas are a few metres apart.

At 3 m and 20 Hz they differ by 6.2 %: a modelling difference, not
discretisation (docs/validation.md (c)): twice the BEM cells per side give
6.4 %, twice the receiver points 6.2 %; loading the source area with the
rigid-punch pressure (as the BEM's rigid area does) instead of the uniform
one takes it to 3.9 % (4x16 cells) / 3.8 % (8x32); the coupling through the
other areas is 0.16 % of it (3 areas instead of 5: 6.37 %); the rest is the
two rigid areas' interaction through the soil.
"""

from __future__ import annotations

import math

import numpy as np

from clm_core.freefield.model import AreaTransfer
from clm_core.halfspace.bem import RowGeometry, RowModel
from clm_core.profile import load_profile


def _chebyshev(n: int) -> np.ndarray:
    return np.cos((2 * np.arange(1, n + 1) - 1) * math.pi / (2 * n))


def bem_errors(freq: float = 20.0, spacing: float = 3.0, source: str = "uniform", cells: tuple[int, int] = (4, 16),
               receiver_points: tuple[int, int] = (6, 48)) -> dict[str, float]:
    """|U_two-step - H_BEM| / |H_BEM| for the neighbour (spacing) and the next one (2 spacing), mevergnies soil.

    ``source``: ``uniform`` (the two-step method's pressure on the loaded area) or ``rigid`` (the rigid-punch
    pressure, Gauss-Chebyshev points with equal weights, as on the receiving area); ``cells``: BEM cells per area
    along and across the track; ``receiver_points``: Chebyshev points over the receiving area.
    """
    soil = load_profile("mevergnies")
    geo = RowGeometry(n_areas=5, spacing=spacing, nx=cells[0], ny=cells[1])
    w = 2.0 * math.pi * freq
    H, _ = RowModel(soil, geo, f_max=freq).solve(w, full=True)
    assert H is not None
    # receiver points: Gauss points over the receiving area (centre x = 0); source areas at +d and +2d
    # weights: the contact pressure of a rigid punch, ~ 1/sqrt(1 - (2x/w)^2) 1/sqrt(1 - (2y/L)^2): Gauss-Chebyshev
    # nodes with equal weights (by Betti's reciprocity a rigid massless area moves as the incident field
    # averaged with its own rigid contact pressure as the weight)
    gx, gy = _chebyshev(receiver_points[0]), _chebyshev(receiver_points[1])
    px = np.repeat(0.5 * geo.width * gx, gy.size)
    py = np.tile(0.5 * geo.length * gy, gx.size)
    sx = np.repeat(0.5 * geo.width * _chebyshev(4), 24)
    sy = np.tile(0.5 * geo.length * _chebyshev(24), 4)
    out = {}
    c = geo.n  # centre area index
    for k in (1, 2):
        if source == "uniform":
            kern = AreaTransfer(soil, k * spacing - px, py, freq, geo.length, geo.width)
        else:  # point loads at the source's Chebyshev points (rigid-punch pressure), point Green's function
            kern = AreaTransfer(soil, (k * spacing + sx[None, :] - px[:, None]).ravel(),
                                (sy[None, :] - py[:, None]).ravel(), freq, 0.0, 0.0)
        u = complex(np.mean(kern(w)))
        h = complex(H[c, c + k])
        out[f"{k * spacing:g} m"] = abs(u - h) / abs(h)
    return out


def test_two_step_vs_bem_within_5_percent() -> None:
    """20 Hz, areas 6 m apart (3.2 % measured); at 3 m the neglected coupling through the neighbours shows (6.2 %)."""
    err = bem_errors(20.0)
    assert err["6 m"] <= 0.05, f"two-step vs BEM at 20 Hz, 6 m: {100 * err['6 m']:.2f} %"
    assert err["3 m"] > err["6 m"]  # the coupling the two-step method leaves out decays with the distance


def test_two_step_vs_bem_low_frequency() -> None:
    """10 Hz: both pairs within 5 % (1.8 % and 1.6 % measured)."""
    err = bem_errors(10.0)
    for key, e in err.items():
        assert e <= 0.05, f"areas {key} apart: two-step vs BEM differ by {100 * e:.2f} %"


def test_the_3_m_difference_is_the_model_not_the_mesh() -> None:
    """20 Hz, 3 m: refining either discretisation moves the 6.2 % little; the rigid source's pressure halves it."""
    base = bem_errors(20.0)["3 m"]
    finer_bem = bem_errors(20.0, cells=(8, 32))["3 m"]
    finer_points = bem_errors(20.0, receiver_points=(12, 96))["3 m"]
    rigid = bem_errors(20.0, source="rigid")["3 m"]
    assert abs(finer_bem - base) < 0.005 and abs(finer_points - base) < 0.001, (base, finer_bem, finer_points)
    assert base > 0.05 and rigid < 0.05 and rigid < 0.7 * base, (base, rigid)
