"""Deprecated import path: use :mod:`clm_core.soil.fit` and :mod:`clm_core.soil.chain`.

Kept only for ``clm_core/halfspace/impact_bag.py`` and its tests while that
module moves to ``clm_core/synthetic`` (issue 11, another branch); it holds no
solver or fit of its own. Delete it once nothing imports it.
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from clm_core.soil.chain import CArray, chain_frequency_response
from clm_core.soil.fit import ClmSumFit, fit_clm_sums

__all__ = ["ClmSumFit", "clm_chain_response", "fit_clm_sums"]


def clm_chain_response(
    freqs: ArrayLike, mf: float, kf: float, df: float, kc: float, dc: float, n_areas: int
) -> CArray:
    """Receptances X_j / F [m/N], shape (n_f, n_areas), of the free CLM chain loaded at its centre.

    The old signature of :func:`clm_core.soil.chain.chain_frequency_response`
    (parameters m_f [kg], k_f [N/m], d_f [N s/m], k_c [N/m], d_c [N s/m]).
    """
    return chain_frequency_response({"mf": mf, "kf": kf, "df": df, "kc": kc, "dc": dc}, n_areas, freqs)
