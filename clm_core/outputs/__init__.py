"""The outputs layer: what a run, a calibration or a study leaves on disk (history files, figures, reports).

It sits above the physics (it reads the results of :mod:`clm_core.online`,
:mod:`clm_core.vehicle`, :mod:`clm_core.calibration` and
:mod:`clm_core.freefield`) and below the studies and the commands that call it;
the bottom layer it writes through is :mod:`clm_core.io` (time base, codec,
bags, files). Modules (one home per concept):

- :mod:`clm_core.outputs.history`: time-history files (NPZ, CSV, JSON);
- :mod:`clm_core.outputs.plots`: every matplotlib figure (import it only where a figure is drawn);
- :mod:`clm_core.outputs.report_index`: the HTML index of an output tree;
- :mod:`clm_core.outputs.calibration_report`: the files of a calibration (parameter YAML, summary, report);
- :mod:`clm_core.outputs.receivers`: the free-field outputs of a finished run (``clm simulate --receivers``).

Submodules are imported on use: importing this package is cheap.
"""
