"""Per-sleeper overrides are applied in one place (clm_core.track.SleeperValues), used by assembly and solver."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clm_core.errors import ParameterError, StabilityError
from clm_core.params import ModelParams, SleeperOverride, load_model
from clm_core.solver import TrackSimulator
from clm_core.track import SleeperValues, assemble, check_overridden_stretches, sleeper_properties


@pytest.fixture(scope="module")
def mev() -> ModelParams:
    return load_model("mevergnies", "mevergnies", "clm")


def test_overrides_apply_in_order_later_wins(mev: ModelParams) -> None:
    p = replace(mev, overrides=(
        SleeperOverride(tuple(range(10, 20)), {"kb": 40e6, "kc": 1e6}),
        SleeperOverride((15, 16, 15), {"kb": 30e6}),
        SleeperOverride((-3,), {"ms": 250.0}),
    ))
    sv = SleeperValues(p)
    assert sv.touched.tolist() == [-3, *range(10, 20)]
    g = np.arange(-5, 25, dtype=np.int64)
    vals = sv.values(g)
    kb = vals["kb"]
    assert kb[g == 15][0] == 30e6 and kb[g == 16][0] == 30e6 and kb[g == 14][0] == 40e6
    assert kb[g == 9][0] == mev.track.kb and kb[g == 20][0] == mev.track.kb
    assert vals["ms"][g == -3][0] == 250.0 and np.count_nonzero(vals["ms"] != mev.track.ms) == 1
    assert sv.touches(19, 1) and not sv.touches(20, 100) and sv.touches(-10, 8) and not sv.touches(-2, 12)
    # the model's per-sleeper arrays are these values (links: kc of sleeper g on link g -> g + 1)
    props = sleeper_properties(p, g, sv)
    np.testing.assert_array_equal(props.kb, kb)
    np.testing.assert_array_equal(props.kc, vals["kc"][:-1])
    assert sv.key(g) != sv.key(g + 100) and sv.key(g + 100) == sv.key(None, g.size)


def test_assembly_is_the_same_with_indexed_values(mev: ModelParams) -> None:
    p = replace(mev, overrides=(SleeperOverride((3, 4), {"kf": 20e6, "dc": -1e3}),))
    a = assemble(p, 12, first_sleeper=-2)
    b = assemble(p, 12, first_sleeper=-2, sleeper_values=SleeperValues(p))
    for A, B in ((a.K, b.K), (a.C, b.C), (a.M, b.M)):
        assert (A != B).nnz == 0
    assert a.props.kf[5] == 20e6 and a.props.kf[4] == mev.soil.kf


def test_solver_windows_use_the_same_values_as_assembly(mev: ModelParams) -> None:
    """The simulator's window over a soft patch carries exactly the track module's per-sleeper values."""
    p = replace(mev, overrides=(SleeperOverride(tuple(range(30, 36)), {"kf": 20e6}),
                                SleeperOverride((20,), {"kb": 4.7e6})))
    sim = TrackSimulator(p, 2e-4, 31, start_position=33 * p.track.spacing)
    s = sim.system
    ref = sleeper_properties(p, s.sleeper_index)
    for name in ("kp", "kb", "db", "kf", "df", "mf", "kc", "dc"):
        np.testing.assert_array_equal(getattr(s.props, name), getattr(ref, name), err_msg=name)
    assert np.count_nonzero(s.props.kf == 20e6) == 6


def test_overridden_stretches_are_checked_far_along_the_line(mev: ModelParams) -> None:
    check_overridden_stretches(mev)  # nothing overridden: nothing to check
    ok = replace(mev, overrides=(SleeperOverride(tuple(range(5000, 5900)), {"kb": 60e6}),))
    check_overridden_stretches(ok)  # 900 sleepers: checked in overlapping pieces
    bad = replace(ok, overrides=(*ok.overrides, SleeperOverride((5850, 5851), {"dc": -400e3})))
    with pytest.raises(StabilityError, match="not positive semi-definite"):
        check_overridden_stretches(bad)
    with pytest.raises(ParameterError, match="kb = -1 at sleeper 7000"):
        check_overridden_stretches(replace(mev, overrides=(SleeperOverride((7000,), {"kb": -1.0}),)))
