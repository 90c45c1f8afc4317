"""Fitting of discrete soil models (CLM, Lysmer) to rigorous or measured impedances.

:mod:`clm_core.fitting.clm_sums` fits the coupled lumped mass (CLM)
parameters to the impedance sums of Kouroussis et al. (2011), Eq. (16) and
(18), in a stated frequency band and error norm.
"""

from clm_core.fitting.clm_sums import (
    ClmSumFit,
    LysmerFit,
    check_chain_positive_definite,
    clm_chain_response,
    fit_clm_sums,
    fit_lysmer,
)

__all__ = [
    "ClmSumFit",
    "LysmerFit",
    "check_chain_positive_definite",
    "clm_chain_response",
    "fit_clm_sums",
    "fit_lysmer",
]
