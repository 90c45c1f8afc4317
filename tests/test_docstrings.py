"""Docstrings that are checked: runnable ``Examples`` on the public entry points, and ``Parameters`` sections
that name the real parameters.

The examples run as doctests here (a failing example fails the suite): the
numbers they print are the model's (a static deflection, a fitted stiffness),
so a change of behaviour shows in the documentation's own test. The
parameter check (tests/docshape.py) compares every numpydoc ``Parameters``
section of a public function, class (its ``__init__``) or method of clm_core
with the signature, both ways.
"""

from __future__ import annotations

import doctest
import importlib
from typing import Any

import pytest

from tests import docshape

#: The public entry points that must show a runnable example (module, attribute path).
ENTRY_POINTS = (
    ("clm_core.solver", "TrackSimulator"),
    ("clm_core.online", "OnlineTrackModel"),
    ("clm_core.online", "OnlineTrackModel.from_settings"),
    ("clm_core.online", "answer"),
    ("clm_core.calibration", "calibrate"),
    ("clm_core.soil.chain", "chain_response"),
    ("clm_core.io.timebase", "lag_figures"),
)
#: The modules whose doctests run (every example in them, entry points or not).
MODULES = sorted({"clm_core.solver.simulator", "clm_core.online.model", "clm_core.online.edge",
                  "clm_core.calibration.api", "clm_core.soil.chain", "clm_core.io.timebase"})


def _resolve(module: str, path: str) -> Any:
    obj: Any = importlib.import_module(module)
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


@pytest.mark.parametrize(("module", "path"), ENTRY_POINTS)
def test_entry_point_has_a_runnable_example(module: str, path: str) -> None:
    obj = _resolve(module, path)
    doc = obj.__doc__ or ""
    assert "\nExamples\n" in doc.replace("    ", ""), f"{module}.{path}: no Examples section"
    examples = doctest.DocTestParser().get_examples(doc)
    assert len(examples) >= 3, f"{module}.{path}: {len(examples)} examples"
    assert obj.__module__ in MODULES, f"{module}.{path} is defined in {obj.__module__}, whose doctests do not run"


@pytest.mark.parametrize("module", MODULES)
def test_doctests_of_the_entry_point_modules_pass(module: str) -> None:
    mod = importlib.import_module(module)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    tests = [t for t in doctest.DocTestFinder().find(mod, module) if t.examples]
    for t in tests:
        runner.run(t)
    res = runner.summarize(verbose=False)
    assert res.attempted > 0 and res.failed == 0, f"{module}: {res.failed} of {res.attempted} examples failed"


def test_parameters_sections_name_the_real_parameters() -> None:
    found = docshape.mismatches()
    assert found == [], "\n".join(found)
    with_section, _ = docshape.counted()
    assert with_section > 150  # the check sees the sections (a parser that found none would pass vacuously)


def test_the_parameters_parser_reads_numpydoc() -> None:
    doc = '''Do it.

    Parameters
    ----------
    a : float
        First [m].
    b, c : array_like
        Two more,
        on two lines.
    *args : object
    flag
        No type.

    Returns
    -------
    x : float
    '''
    assert docshape.documented(doc) == ["a", "b", "c", "args", "flag"]
    assert docshape.documented("One line.") is None

    def f(a: float, b: Any, c: Any, *args: object, flag: bool = False) -> float:
        return a

    assert docshape.real(f) == ["a", "b", "c", "args", "flag"]
