"""The package's structure: no import circles (``tools/import_graph.py``, ``TYPE_CHECKING``
imports and imports inside functions included), and the task's vocabulary — the objective and
phase names — spelled out in one module only (``ahrm_stack/names.py``)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))

import import_graph  # noqa: E402


def test_no_import_circle_even_through_type_checking_or_lazy_imports():
    known = import_graph.modules()
    found = import_graph.edges(known)
    assert ("ahrm_stack.config.task", "ahrm_stack.config.layout_rules") in {(e.source, e.target) for e in found}
    assert import_graph.circles(import_graph.graph_of(found, known, typing=True)) == []


def test_the_lower_layers_import_nothing_above_them():
    """``hardware/`` (the protocol and the real arms' adapters), ``config/`` and ``realism/`` import
    nothing of the simulation, training or deploy, lazily or for typing included: the sim arm lives
    above the task (``ahrm_stack.sim_arm``), the layout rules and the realism schema below config."""
    found = import_graph.edges(import_graph.modules())
    above = ("ahrm_stack.env", "ahrm_stack.learning", "ahrm_stack.deploy", "ahrm_stack.sim_arm",
             "ahrm_stack.robustness", "ahrm_stack.evaluation")
    for layer in ("ahrm_stack.hardware", "ahrm_stack.config", "ahrm_stack.realism"):
        up = sorted((e.source, e.target) for e in found
                    if e.source.startswith(layer) and e.target.startswith(above))
        assert up == [], up


def test_the_circle_finder_finds_a_circle():
    assert import_graph.circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_objective_and_phase_names_are_spelled_out_once():
    from ahrm_stack.names import OBJECTIVE_NAMES, PHASE_NAMES

    spelled = [re.compile(r"""["']avoid["'],\s*["']manipulate["']"""),
               re.compile(r"""["']approach["'],\s*["']pre-manipulate["']"""),
               re.compile(r"Phase 2 \(pre-manipulate\)")]
    where = [str(path.relative_to(ROOT)) for folder in ("ahrm_stack", "studies", "benchmarks")
             for path in sorted((ROOT / folder).rglob("*.py"))
             if any(p.search(path.read_text()) for p in spelled)]
    assert where == ["ahrm_stack/names.py"]
    assert OBJECTIVE_NAMES == ("avoid", "manipulate", "time")
    assert PHASE_NAMES == ("approach", "pre-manipulate", "manipulate")
