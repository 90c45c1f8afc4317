"""Foundation models of the soil under the sleepers (paper Sec. 3–4).

- :mod:`clm_core.soil.formulas`: closed-form formulas (Eq. 3, 5, 6, 21, 23,
  24, 26) and Lysmer's analogue from soil properties.
- :mod:`clm_core.soil.chain`: the CLM chain of 2n+1 contact areas alone, in the
  frequency domain (Eq. 9–20) and in the time domain.
"""
