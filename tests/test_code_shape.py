"""The shape of clm_core that no linter rule holds (issue 22): no private reach-ins across units.

A *unit* is a subpackage of clm_core or a module at its top (tests/codeshape.py
scans the source, nothing is imported). Inside a unit, modules may share
private names (the simulator's collaborators, a package's helpers); across
units only public names are used: ``obj._name`` where ``_name`` is private to
another unit (e.g. ``sim._s`` of :class:`clm_core.solver.TrackSimulator` from
:mod:`clm_core.online`), or an import from another unit's private module
(``clm_core.solver._frame_kernel``).
"""

from __future__ import annotations

from tests import codeshape


def test_no_module_reaches_into_another_units_private_attributes() -> None:
    found = [str(r) for r in codeshape.reach_ins() if not r.expr.startswith("from ")]
    assert found == [], "\n".join(found)


def test_private_modules_and_names_are_imported_only_inside_their_unit() -> None:
    """No ``from clm_core.x import _name``, ``from clm_core.x._mod import name`` or ``import clm_core.x._mod``
    across units (issue 22: the input policy imported the solver's ``_frame_kernel``; one left before, none now)."""
    found = [str(r) for r in codeshape.reach_ins() if r.expr.startswith(("from ", "import "))]
    assert found == [], "\n".join(found)


def test_the_ros_layer_imports_only_the_cores_public_names() -> None:
    """clm_ros (nodes, its ``clm`` commands) imports no private module or name of clm_core (its commands
    imported ``clm_core.commands._common``/``_options``: now the public ``clm_core.commands``)."""
    assert codeshape.core_private_imports() == []
    probe = ("from clm_core.commands._common import add_command\nfrom clm_core.solver import _kernels, TrackSimulator\n"
             "import clm_core.io._rosbag2\nfrom clm_core.commands import add_setting\n")
    assert [s.split(" ", 1)[1] for s in codeshape.core_private_imports(source=probe)] == [
        "from clm_core.commands._common import add_command", "from clm_core.solver import _kernels",
        "import clm_core.io._rosbag2"]


def test_the_scan_sees_a_reach_in() -> None:
    """The scanner is not blind: in a probe module of ``online``, ``sim._s`` (the simulator's state) and an
    import of the solver's private kernel module are found; ``self._s`` and ``rec._of`` (online's own) are not."""
    probe = ("from clm_core.solver._kernels import run_steps\n"
             "from clm_core.solver import _frame_kernel, TrackSimulator\n"
             "from clm_core.online import _probe_helper\n"
             "def f(sim, self, rec):\n    import clm_core.solver._frame_kernel\n"
             "    return sim._s.k + self._s + rec._of\n")
    found = [r.expr for r in codeshape.reach_ins({"clm_core.online.probe": probe}) if r.module.endswith("probe")]
    assert sorted(found) == ["from clm_core.solver import _frame_kernel",
                             "from clm_core.solver._kernels import run_steps",
                             "import clm_core.solver._frame_kernel", "sim._s"]


def test_no_module_over_700_lines() -> None:
    assert codeshape.long_modules(700) == []
