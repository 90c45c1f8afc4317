"""Files, messages and figures at the edge of the core.

Modules (one home per concept): :mod:`clm_core.io.history` (time-history
files: NPZ, CSV, JSON), :mod:`clm_core.io.plots` (every matplotlib figure;
import it only where a figure is drawn), :mod:`clm_core.io.report_index`
(the HTML index of an output tree).
"""
