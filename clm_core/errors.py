"""Exception types of clm_core.

Every error says what was wrong and where: the parameter, its value and the
rule it broke.
"""


class ClmError(Exception):
    """Base class of all clm_core errors."""


class ParameterError(ClmError, ValueError):
    """A parameter value is invalid (NaN, wrong sign, out of range, unknown name)."""


class StabilityError(ParameterError):
    """A parameter set gives an assembled system that is not stable.

    Raised when the damping matrix of the whole system is not positive
    definite (Kouroussis et al. 2011, Sec. 4.2), which would make a time
    integration diverge.
    """


class PresetError(ParameterError):
    """An unknown preset name or an unreadable parameter file."""


class InputError(ClmError, ValueError):
    """Bad run-time input (loads, times, sizes, files)."""
