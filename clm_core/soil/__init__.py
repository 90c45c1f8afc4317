"""Foundation models of the soil under the sleepers (paper Sec. 3-4).

- :mod:`clm_core.soil.chain`: the CLM chain of 2n + 1 contact areas alone, the
  project's one chain solver: receptances at any Laplace variable with their
  Jacobian, the total and alternating sums (Eq. 9-20), the time response.
- :mod:`clm_core.soil.formulas`: closed-form formulas (Eq. 3, 5, 6, 16, 18, 21,
  22, 23, 24, 26) and Lysmer's analogue from soil properties.
- :mod:`clm_core.soil.fit`: fits of the CLM parameters to the sums of
  Eq. (16) and (18) (joint or total-first) and of Lysmer's analogue (Eq. 3), in
  a stated band and norm.

Value rules (signs, chain stability) live in :mod:`clm_core.checks`.
"""
