"""``tools/mutate.py``, the mutation-testing command, kept from rotting: its operators on a small
module, what it leaves alone, and one whole run on one small function (a few seconds). The runs over
the project's modules are a command (``python tools/mutate.py --suite``), not part of the suite."""

from __future__ import annotations

import ast
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))

import mutate  # noqa: E402

SOURCE = textwrap.dedent('''
    """A module docstring: 1 < 2 is never mutated."""
    from typing import TYPE_CHECKING

    if TYPE_CHECKING:
        LIMIT = 1 + 2

    __all__ = ["clamp"]


    def clamp(x: float, low: float = 0.0, high: float = 1.0) -> float:
        """Docstring."""
        if x < low:
            return low
        return min(x, high)


    def first_positive(values) -> int:
        for i, v in enumerate(values):
            if not v > 0 and True:
                continue
            return i
        raise ValueError(f"none of {len(values) - 1} values")


    def spin(n):
        while n:
            n -= 1
            print(n)
        return -n  # no mutate: a line the author showed equivalent
''')


def _changes(source: str = SOURCE) -> list[str]:
    return [f"{m.line}: {m.change}" for m in mutate.mutants(source)]


def test_the_operators_cover_comparisons_arithmetic_logic_constants_calls_and_statements():
    changes = _changes()
    for expected in ["13: if condition negated", "13: `<` -> `<=`", "13: `<` -> `>=`",
                     "14: `return x` -> `return None`", "15: `min(...)` -> `max(...)`",
                     "11: `0.0` -> `1.0`", "11: `1.0` -> `2.0`",
                     "20: `not x` -> `x`", "20: `and` -> `or`", "20: `>` -> `>=`", "20: `True` -> `False`",
                     "21: `continue` -> `pass`", "23: `raise ...` -> `pass`",
                     "27: while condition negated", "28: `-=` -> `+=`", "29: `print(...)` -> `pass`"]:
        assert expected in changes, expected


def test_docstrings_f_strings_annotations_all_type_checking_and_marked_lines_are_left_alone():
    changes = _changes()
    lines = {int(c.split(":")[0]) for c in changes}
    assert not lines & {2, 5, 6, 8, 12, 30}  # docstrings, TYPE_CHECKING, __all__, "# no mutate"
    assert not [c for c in changes if c.startswith("23: `-`") or c.startswith("23: `1`")]  # inside the f-string


def test_a_mutant_changes_one_node_and_keeps_the_line_numbers():
    found = mutate.mutants(SOURCE)
    swap = next(m for m in found if m.change == "`min(...)` -> `max(...)`")
    tree = mutate.mutated_tree(SOURCE, swap)
    text = ast.unparse(tree)
    assert "return max(x, high)" in text and "min(" not in text
    assert ast.unparse(ast.parse(SOURCE)).replace("min(", "max(") == text
    namespace: dict = {}
    exec(compile(tree, "<mutant>", "exec"), namespace)
    assert namespace["clamp"](0.5, 0.0, 0.25) == 0.5  # max(0.5, 0.25): the mutant's answer
    deleted = next(m for m in found if m.change == "`raise ...` -> `pass`")
    function = next(n for n in ast.walk(mutate.mutated_tree(SOURCE, deleted))
                    if isinstance(n, ast.FunctionDef) and n.name == "first_positive")
    assert isinstance(function.body[-1], ast.Pass) and function.body[-1].lineno == 23


def test_a_run_on_one_function_kills_what_its_tests_see_and_names_the_survivors(tmp_path):
    (tmp_path / "clamping.py").write_text(textwrap.dedent('''
        def clamp(x, low, high):
            if x < low:
                return low
            return min(x, high)
    '''))
    (tmp_path / "test_clamping.py").write_text(textwrap.dedent('''
        from clamping import clamp

        def test_clamp():
            assert clamp(-1, 0, 1) == 0 and clamp(0.5, 0, 1) == 0.5 and clamp(2, 0, 1) == 1
    '''))  # x == low is never tried: `<` -> `<=` survives
    printed: list[str] = []
    outcomes = mutate.mutate_file(tmp_path / "clamping.py", ["test_clamping.py"], root=tmp_path, echo=printed.append)
    assert [(o.mutant.line, o.mutant.change, o.result) for o in outcomes] == [
        (3, "if condition negated", "killed"), (3, "`<` -> `<=`", "survived"), (3, "`<` -> `>=`", "killed"),
        (4, "`return x` -> `return None`", "killed"), (5, "`return x` -> `return None`", "killed"),
        (5, "`min(...)` -> `max(...)`", "killed")]
    assert printed[1:] == ["  survived  clamping.py:3:8  `<` -> `<=`  | if x < low:",
                           "  clamping.py: 5 / 6 killed (83 %)"]
    assert (tmp_path / "clamping.py").read_text().count("x < low") == 1  # the file itself is never changed


def test_the_forked_runs_give_what_the_fresh_processes_give(tmp_path):
    """--fork: each mutant's tests in a child of a process that imported their dependencies once;
    the same outcomes as a fresh interpreter per mutant."""
    (tmp_path / "clamping.py").write_text(textwrap.dedent('''
        import numpy as np

        def clamp(x, low, high):
            if x < low:
                return low
            return float(np.minimum(x, high))
    '''))
    (tmp_path / "test_clamping.py").write_text(textwrap.dedent('''
        from clamping import clamp

        def test_clamp():
            assert clamp(-1, 0, 1) == 0 and clamp(0.5, 0, 1) == 0.5 and clamp(2, 0, 1) == 1
    '''))
    fresh = mutate.mutate_file(tmp_path / "clamping.py", ["test_clamping.py"], root=tmp_path, echo=lambda _: None)
    forked = mutate.mutate_file(tmp_path / "clamping.py", ["test_clamping.py"], root=tmp_path, echo=lambda _: None,
                                fork=True)
    assert [(o.mutant.index, o.result) for o in forked] == [(o.mutant.index, o.result) for o in fresh]
    assert [o.result for o in fresh].count("survived") == 1 and len(fresh) == 6
    assert "clamping" not in sys.modules  # the children imported the project, not this process
