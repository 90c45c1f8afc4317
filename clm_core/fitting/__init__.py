"""Former home of the CLM sums fit; moved to :mod:`clm_core.soil.fit` (issue 11).

Only :mod:`clm_core.fitting.clm_sums` remains, as a re-export for
``clm_core/halfspace/impact_bag.py`` while that module moves to
``clm_core/synthetic`` (another branch). Delete the package once nothing imports it.
"""
