"""Mutation testing with a small AST mutator: do a module's fast tests notice when its code changes?

    python tools/mutate.py ahrm_stack/hardware/protocol.py --tests tests/test_protocol.py
    python tools/mutate.py --suite                      # every module of SUITE, a table at the end
    python tools/mutate.py --suite --only protocol      # the SUITE rows whose module path has "protocol"
    python tools/mutate.py FILE --tests T --list        # the mutants only, nothing run

One mutant at a time: the module is parsed, one node is changed (the operators below), and the
given test files run with ``pytest -x -q`` in a fresh process (the repository root as working
folder, ``CI=1`` so that hypothesis draws a fixed sequence). A test run that fails or errors, or runs
past ``--timeout`` (default: ten times the unmutated run, at least 20 s), *kills* the mutant; one
that passes lets it *survive*. Survivors are printed as ``file:line:col  change  | source line``,
then the score ``killed / mutants``.

The source file itself is never written: a ``sitecustomize`` module on ``PYTHONPATH`` of the test
process (and of every Python process it starts) compiles the mutated tree in place of the module
when it is imported, keeping the file's line numbers. The unmutated tests must pass first.

Operators (one change per mutant):

* comparisons: ``<`` to ``<=`` and ``>=``, ``<=`` to ``<`` and ``>``, likewise ``>``, ``>=``;
  ``==`` / ``!=``, ``is`` / ``is not``, ``in`` / ``not in`` swapped;
* arithmetic: ``+`` / ``-``, ``*`` / ``/``, ``//`` to ``/``, ``%`` and ``**`` to ``*``, ``&`` / ``|``
  swapped, augmented assignments likewise; a unary ``-``, ``not`` or ``~`` removed;
* ``and`` / ``or`` swapped; an ``if``, ``elif``, ``while``, conditional expression or comprehension
  condition negated;
* numbers: n to n + 1; ``True`` / ``False`` swapped;
* calls: ``min`` / ``max``, ``minimum`` / ``maximum``, ``any`` / ``all``, ``floor`` / ``ceil``,
  ``argmin`` / ``argmax`` swapped (as a name or an attribute);
* statements: ``continue``, ``break``, ``raise ...`` and a bare call statement replaced by ``pass``;
  ``return x`` by ``return None``.

Not mutated: docstrings and other strings, f-strings (messages), annotations, ``__all__``, the
body of ``if TYPE_CHECKING:``, and lines with a ``# no mutate`` comment (for a mutant shown
equivalent; say why in the comment).

The runs are a command, not part of the test suite (minutes per module); ``tests/test_mutate.py``
runs the mutator on one small function to keep it working.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib.abc
import importlib.machinery
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

ROOT = Path(__file__).resolve().parent.parent
SPEC_VARIABLE = "MUTATE_SPEC"  # {"module": dotted name, "path": source file, "index": mutant index}
SKIP_MARK = "# no mutate"

#: test_safety.py without its property tests (hypothesis, minutes): its fast closed-form cases
SAFETY_FAST = ("not hard_bound and not keep_the_hard_bounds and not hypothesis_floats and not analytic_clip "
               "and not meets_every_coupled_row and not agree and not random_policy_episode")
_CONSTRAINT_TESTS = (("tests/test_constraints_fast.py", "tests/test_safety.py", "tests/test_safety_fast_path.py",
                      "tests/test_safety_active_box.py"), SAFETY_FAST)

#: The modules of the documented run (``--suite``) and their fast tests: (test files, a ``pytest -k``
#: expression or ""), each run a few seconds at most.
SUITE: dict[str, tuple[tuple[str, ...], str]] = {
    "ahrm_stack/safety/constraints/position.py": _CONSTRAINT_TESTS,
    "ahrm_stack/safety/constraints/velocity.py": _CONSTRAINT_TESTS,
    "ahrm_stack/safety/constraints/acceleration.py": _CONSTRAINT_TESTS,
    "ahrm_stack/safety/constraints/table.py": _CONSTRAINT_TESTS,
    "ahrm_stack/safety/constraints/workspace.py": _CONSTRAINT_TESTS,
    "ahrm_stack/deploy/safety_settings.py": (("tests/test_safety_settings.py",), ""),
    "ahrm_stack/hardware/protocol.py": (("tests/test_protocol.py", "tests/test_kortex_pure.py"), ""),
    "ahrm_stack/learning/mechanisms.py": (("tests/test_mechanisms.py",), ""),
    "ahrm_stack/env/rewards.py": (("tests/test_rewards.py",), ""),
    "ahrm_stack/kinematics/phases.py": (("tests/test_phases.py",), ""),
    # the live QP core (issue 57, item 7)
    "ahrm_stack/safety/solvers.py": (("tests/test_solvers.py", *_CONSTRAINT_TESTS[0]), SAFETY_FAST),
    "ahrm_stack/safety/constraints/base.py": (("tests/test_kinematic_snapshot.py", *_CONSTRAINT_TESTS[0]),
                                              SAFETY_FAST),
    "ahrm_stack/safety/constraints/distance.py": (("tests/test_distance_rows_fast.py",
                                                   "tests/test_constraints_fast.py"), ""),
    "ahrm_stack/safety/filter.py": (("tests/test_safety_filter_definition.py", "tests/test_safety_filter_internals.py",
                                     "tests/test_safety_filter_paths.py", *_CONSTRAINT_TESTS[0]), SAFETY_FAST),
}

_SWAPPED_CALLS = {"min": "max", "max": "min", "minimum": "maximum", "maximum": "minimum", "any": "all",
                  "all": "any", "floor": "ceil", "ceil": "floor", "argmin": "argmax", "argmax": "argmin"}
_COMPARE: dict[type, tuple[type, ...]] = {
    ast.Lt: (ast.LtE, ast.GtE), ast.LtE: (ast.Lt, ast.Gt), ast.Gt: (ast.GtE, ast.LtE),
    ast.GtE: (ast.Gt, ast.Lt), ast.Eq: (ast.NotEq,), ast.NotEq: (ast.Eq,), ast.Is: (ast.IsNot,),
    ast.IsNot: (ast.Is,), ast.In: (ast.NotIn,), ast.NotIn: (ast.In,)}
_BINARY: dict[type, type] = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult,
                             ast.FloorDiv: ast.Div, ast.Mod: ast.Mult, ast.Pow: ast.Mult,
                             ast.BitAnd: ast.BitOr, ast.BitOr: ast.BitAnd}
_SYMBOL: dict[type, str] = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!=",
           ast.Is: "is", ast.IsNot: "is not", ast.In: "in", ast.NotIn: "not in", ast.Add: "+",
           ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.FloorDiv: "//", ast.Mod: "%", ast.Pow: "**",
           ast.BitAnd: "&", ast.BitOr: "|", ast.USub: "-", ast.Not: "not ", ast.Invert: "~",
           ast.And: "and", ast.Or: "or"}


@dataclasses.dataclass(frozen=True)
class Mutant:
    """One change: node ``node`` of the module's pre-order walk (:func:`_walk`), variant ``variant``
    of the changes listed for it; ``line``/``column`` where it is (1-based line), ``change`` says
    what it does."""

    index: int
    node: int
    variant: int
    line: int
    column: int
    change: str


# ------------------------------------------------------------------------------------ the mutants


def _walk(tree: ast.AST) -> list[tuple[ast.AST, ast.AST | None]]:
    """Every node of ``tree`` with its parent, in source (pre-)order, leaving out what is never
    mutated (docstrings, f-strings, annotations, ``__all__``, ``if TYPE_CHECKING:`` bodies)."""
    out: list[tuple[ast.AST, ast.AST | None]] = []

    def visit(node: ast.AST, parent: ast.AST | None) -> None:
        out.append((node, parent))
        for field, value in ast.iter_fields(node):
            if field in ("annotation", "returns", "type_comment"):
                continue
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) \
                    and field == "body" and value and _is_docstring(value[0]):
                value = value[1:]
            children = value if isinstance(value, list) else [value]
            for child in children:
                if not isinstance(child, ast.AST) or isinstance(child, ast.JoinedStr):
                    continue
                if isinstance(child, ast.If) and _is_type_checking(child.test):
                    continue
                if isinstance(child, ast.Assign) and any(
                        isinstance(t, ast.Name) and t.id == "__all__" for t in child.targets):
                    continue
                visit(child, node)

    visit(tree, None)
    return out


def _is_docstring(statement: ast.stmt) -> bool:
    return (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)
            and isinstance(statement.value.value, str))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _negate(expression: ast.expr) -> ast.expr:
    return ast.UnaryOp(op=ast.Not(), operand=expression)


def _replace(parent: ast.AST, old: ast.AST, new: ast.AST) -> None:
    """Put ``new`` where ``old`` is among ``parent``'s fields."""
    for field, value in ast.iter_fields(parent):
        if isinstance(value, list):
            for i, item in enumerate(value):
                if item is old:
                    value[i] = new
                    return
        elif value is old:
            setattr(parent, field, new)
            return
    raise ValueError("node not found in its parent")


def _pass_like(old: ast.stmt) -> ast.stmt:
    return ast.copy_location(ast.Pass(), old)


Change = tuple[str, Callable[[ast.AST, ast.AST | None], None]]


def _changes(node: ast.AST, parent: ast.AST | None) -> list[Change]:
    """The mutations of one node: (description, apply(node, parent)), in a fixed order."""
    out: list[Change] = []
    if isinstance(node, ast.Compare):
        for k, op in enumerate(node.ops):
            for new in _COMPARE.get(type(op), ()):
                def swap(n: ast.AST, p: ast.AST | None, k: int = k, new: type = new) -> None:
                    n.ops[k] = new()  # type: ignore[attr-defined]
                out.append((f"`{_SYMBOL[type(op)]}` -> `{_SYMBOL[new]}`", swap))
    elif isinstance(node, (ast.BinOp, ast.AugAssign)) and type(node.op) in _BINARY:
        new = _BINARY[type(node.op)]

        def binary(n: ast.AST, p: ast.AST | None, new: type = new) -> None:
            n.op = new()  # type: ignore[attr-defined]
        equals = "=" if isinstance(node, ast.AugAssign) else ""
        out.append((f"`{_SYMBOL[type(node.op)]}{equals}` -> `{_SYMBOL[new]}{equals}`", binary))
    elif isinstance(node, ast.UnaryOp) and type(node.op) in (ast.USub, ast.Not, ast.Invert) and parent is not None:
        def drop(n: ast.AST, p: ast.AST | None) -> None:
            assert p is not None
            _replace(p, n, n.operand)  # type: ignore[attr-defined]
        out.append((f"`{_SYMBOL[type(node.op)]}x` -> `x`", drop))
    elif isinstance(node, ast.BoolOp):
        new = ast.Or if isinstance(node.op, ast.And) else ast.And

        def boolean(n: ast.AST, p: ast.AST | None, new: type = new) -> None:
            n.op = new()  # type: ignore[attr-defined]
        out.append((f"`{_SYMBOL[type(node.op)]}` -> `{_SYMBOL[new]}`", boolean))
    elif isinstance(node, ast.Constant) and isinstance(node.value, bool):
        def flip(n: ast.AST, p: ast.AST | None) -> None:
            n.value = not n.value  # type: ignore[attr-defined]
        out.append((f"`{node.value}` -> `{not node.value}`", flip))
    elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        def bump(n: ast.AST, p: ast.AST | None) -> None:
            n.value = n.value + 1  # type: ignore[attr-defined]
        out.append((f"`{node.value!r}` -> `{node.value + 1!r}`", bump))
    elif isinstance(node, (ast.If, ast.While, ast.IfExp)):
        def negate(n: ast.AST, p: ast.AST | None) -> None:
            n.test = _negate(n.test)  # type: ignore[attr-defined]
        what = {ast.If: "if", ast.While: "while", ast.IfExp: "conditional expression"}[type(node)]
        out.append((f"{what} condition negated", negate))
    elif isinstance(node, ast.comprehension):
        for k in range(len(node.ifs)):
            def negate_filter(n: ast.AST, p: ast.AST | None, k: int = k) -> None:
                n.ifs[k] = _negate(n.ifs[k])  # type: ignore[attr-defined]
            out.append(("comprehension condition negated", negate_filter))
    elif isinstance(node, (ast.Name, ast.Attribute)) and isinstance(parent, ast.Call) and parent.func is node:
        name = node.id if isinstance(node, ast.Name) else node.attr
        if name in _SWAPPED_CALLS:
            def call(n: ast.AST, p: ast.AST | None, new: str = _SWAPPED_CALLS[name]) -> None:
                setattr(n, "id" if isinstance(n, ast.Name) else "attr", new)
            out.append((f"`{name}(...)` -> `{_SWAPPED_CALLS[name]}(...)`", call))
    elif isinstance(node, (ast.Continue, ast.Break, ast.Raise)) or (
            isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)):
        statement = node.value if isinstance(node, ast.Expr) else None
        what = {ast.Continue: "continue", ast.Break: "break", ast.Raise: "raise ..."}.get(
            type(node), f"{ast.unparse(statement.func) if isinstance(statement, ast.Call) else ''}(...)")

        def delete(n: ast.AST, p: ast.AST | None) -> None:
            assert p is not None
            _replace(p, n, _pass_like(n))  # type: ignore[arg-type]
        out.append((f"`{what}` -> `pass`", delete))
    elif isinstance(node, ast.Return) and node.value is not None and not (
            isinstance(node.value, ast.Constant) and node.value.value is None):
        def nothing(n: ast.AST, p: ast.AST | None) -> None:
            n.value = ast.Constant(value=None)  # type: ignore[attr-defined]
        out.append(("`return x` -> `return None`", nothing))
    return out


def mutants(source: str) -> list[Mutant]:
    """Every mutant of ``source``, numbered in source order."""
    lines = source.splitlines()
    found: list[Mutant] = []
    for position, (node, parent) in enumerate(_walk(ast.parse(source))):
        line = getattr(node, "lineno", 0)
        if line and SKIP_MARK in lines[line - 1]:
            continue
        for variant, (change, _) in enumerate(_changes(node, parent)):
            found.append(Mutant(len(found), position, variant, line, getattr(node, "col_offset", 0) + 1, change))
    return found


def mutated_tree(source: str, mutant: Mutant) -> ast.Module:
    """``source`` parsed, with ``mutant`` applied (line numbers kept)."""
    tree = ast.parse(source)
    node, parent = _walk(tree)[mutant.node]
    _changes(node, parent)[mutant.variant][1](node, parent)
    return ast.fix_missing_locations(tree)


# ------------------------------------------------------------------- the hook in the test process


class _MutantLoader(importlib.machinery.SourceFileLoader):
    """Loads the mutated tree in place of the module's file (no bytecode cache read or written)."""

    def __init__(self, fullname: str, path: str, index: int) -> None:
        super().__init__(fullname, path)
        self.index = index

    def get_code(self, fullname: str):  # type: ignore[override]
        source = Path(self.path).read_text()
        return compile(mutated_tree(source, mutants(source)[self.index]), self.path, "exec")


class _MutantFinder(importlib.abc.MetaPathFinder):
    def __init__(self, module: str, path: str, index: int) -> None:
        self.module, self.path, self.index = module, path, index

    def find_spec(self, fullname, path=None, target=None):  # type: ignore[no-untyped-def]
        if fullname != self.module:
            return None
        loader = _MutantLoader(fullname, self.path, self.index)
        is_package = Path(self.path).name == "__init__.py"
        return importlib.util.spec_from_file_location(
            fullname, self.path, loader=loader,
            submodule_search_locations=[str(Path(self.path).parent)] if is_package else None)


def install_from_environment() -> None:
    """Called by the test process's ``sitecustomize``: put the mutant of ``$MUTATE_SPEC`` first on
    ``sys.meta_path``."""
    spec = os.environ.get(SPEC_VARIABLE)
    if spec:
        wanted = json.loads(spec)
        sys.meta_path.insert(0, _MutantFinder(wanted["module"], wanted["path"], int(wanted["index"])))


_SITECUSTOMIZE = """import sys
sys.path.insert(0, {tools!r})
import mutate
mutate.install_from_environment()
"""


# ------------------------------------------------------------------------------------- running


@dataclasses.dataclass
class Outcome:
    """What the tests did to one mutant: ``killed`` (failed or errored), ``timeout`` (also a kill) or
    ``survived``; ``seconds`` of wall time."""

    mutant: Mutant
    result: str
    seconds: float


def module_name(path: Path, root: Path) -> str:
    parts = path.resolve().relative_to(root.resolve()).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _run_fresh(tests: Sequence[str], root: Path, site: Path, spec: dict | None, timeout: float,
               select: str = "") -> tuple[str, float]:
    environment = dict(os.environ, CI="1", PYTHONDONTWRITEBYTECODE="1")
    environment["PYTHONPATH"] = os.pathsep.join(
        [str(site), str(root)] + ([environment["PYTHONPATH"]] if environment.get("PYTHONPATH") else []))
    environment.pop(SPEC_VARIABLE, None)
    if spec is not None:
        environment[SPEC_VARIABLE] = json.dumps(spec)
    command = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    if select:
        command += ["-k", select]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=root, env=environment, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - start
    seconds = time.perf_counter() - start
    if spec is None and done.returncode != 0:
        sys.stdout.write(done.stdout.decode(errors="replace")[-3000:])
    return ("survived" if done.returncode == 0 else "killed"), seconds


_LISTER = """import json, sys
import pytest
sys.exit_code = pytest.main(sys.argv[1:] + ["-q", "-p", "no:cacheprovider", "--co"])
print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} - {'ahrm_stack', 'tests', 'conftest', '__main__'})),
      file=open(sys.argv[0] + '.json', 'w'))
"""


class ForkRunner:
    """Runs the tests in a child forked from this process after the tests' third-party imports
    (MuJoCo, Pinocchio, NumPy, pytest, ...) are done here once: a mutant costs the tests' own time,
    not the interpreter's start and the imports (several seconds each). Nothing of the project is
    imported here, so each child imports it afresh, the mutant in place of its module. POSIX only.

    The imports are those that collecting the tests imports (listed by a child interpreter once).
    A child's outcome is pytest's exit status, as with a fresh process; a child past the timeout is
    killed (a kill)."""

    def __init__(self, tests: Sequence[str], root: Path, select: str) -> None:
        self.tests, self.root, self.select = list(tests), root, select
        with tempfile.TemporaryDirectory(prefix="mutate-list-") as folder:
            script = Path(folder, "list.py")
            script.write_text(_LISTER)
            environment = dict(os.environ, CI="1", PYTHONDONTWRITEBYTECODE="1")
            environment["PYTHONPATH"] = os.pathsep.join([str(root)] + ([environment["PYTHONPATH"]]
                                                                        if environment.get("PYTHONPATH") else []))
            subprocess.run([sys.executable, str(script), *self.tests], cwd=root, env=environment,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
            listed = Path(str(script) + ".json")
            names = json.loads(listed.read_text()) if listed.is_file() else []
        for name in names:
            if name.startswith("_") or name in sys.builtin_module_names:
                continue
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - a module that does not import alone stays for the child
                pass

    def run(self, spec: dict | None, timeout: float) -> tuple[str, float]:
        start = time.perf_counter()
        pid = os.fork()
        if pid == 0:  # the child: the mutant first on the meta path, then pytest in this process
            code = 3
            try:
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, 1)
                os.dup2(null, 2)
                os.chdir(self.root)
                os.environ["CI"] = "1"  # as the fresh process has it: hypothesis's fixed sequence
                sys.dont_write_bytecode = True
                sys.path.insert(0, str(self.root))
                if spec is not None:
                    sys.meta_path.insert(0, _MutantFinder(spec["module"], spec["path"], int(spec["index"])))
                import pytest

                arguments = ["-x", "-q", "-p", "no:cacheprovider", *self.tests]
                code = int(pytest.main(arguments + (["-k", self.select] if self.select else [])))
            finally:
                os._exit(code)
        deadline = start + timeout
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                seconds = time.perf_counter() - start
                return ("survived" if os.waitstatus_to_exitcode(status) == 0 else "killed"), seconds
            if time.perf_counter() > deadline:
                os.kill(pid, 9)
                os.waitpid(pid, 0)
                return "timeout", time.perf_counter() - start
            time.sleep(0.005)


def mutate_file(path: Path, tests: Sequence[str], root: Path = ROOT, timeout: float | None = None,
                select: str = "", echo: Callable[[str], None] = print, fork: bool = False) -> list[Outcome]:
    """Run ``tests`` (``pytest -k select`` when given) against every mutant of ``path``; prints one
    line per survivor. ``fork``: each run in a child of a process that did the tests' imports once
    (:class:`ForkRunner`), not in a fresh interpreter."""
    source = path.read_text()
    found = mutants(source)
    lines = source.splitlines()
    shown = path.resolve().relative_to(root.resolve())
    with tempfile.TemporaryDirectory(prefix="mutate-site-") as site:
        Path(site, "sitecustomize.py").write_text(_SITECUSTOMIZE.format(tools=str(Path(__file__).resolve().parent)))
        runner = ForkRunner(tests, root, select) if fork else None

        def _run_tests(tests: Sequence[str], root: Path, site: Path, spec: dict | None, timeout: float,
                       select: str = "") -> tuple[str, float]:
            if runner is not None:
                return runner.run(spec, timeout)
            return _run_fresh(tests, root, site, spec, timeout, select)

        result, baseline = _run_tests(tests, root, Path(site), None, 3600.0, select)
        if result != "survived":
            raise SystemExit(f"{shown}: the tests fail without any mutant ({' '.join(tests)}); fix them first")
        limit = timeout if timeout is not None else max(20.0, 10 * baseline)
        echo(f"{shown}: {len(found)} mutants, tests {' '.join(tests)}{' -k ...' if select else ''} "
             f"({baseline:.1f} s unmutated)")
        outcomes = []
        for mutant in found:
            spec = {"module": module_name(path, root), "path": str(path.resolve()), "index": mutant.index}
            result, seconds = _run_tests(tests, root, Path(site), spec, limit, select)
            outcomes.append(Outcome(mutant, result, seconds))
            if result == "survived":
                echo(f"  survived  {shown}:{mutant.line}:{mutant.column}  {mutant.change}  "
                     f"| {lines[mutant.line - 1].strip()[:100]}")
    killed = sum(o.result != "survived" for o in outcomes)
    echo(f"  {shown}: {killed} / {len(outcomes)} killed ({_percent(killed, len(outcomes))})")
    return outcomes


def _percent(part: int, whole: int) -> str:
    return f"{100 * part / whole:.0f} %" if whole else "-"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="*", type=Path, help="modules to mutate (paths from --root)")
    parser.add_argument("--tests", nargs="+", default=[], help="the test files to run against each mutant")
    parser.add_argument("-k", dest="select", default="", help="a pytest -k expression for those tests")
    parser.add_argument("--suite", action="store_true", help="the modules of SUITE with their fast tests")
    parser.add_argument("--only", default="", help="with --suite: the rows whose path contains this")
    parser.add_argument("--timeout", type=float, default=None, help="s per test run (default: 10 x unmutated)")
    parser.add_argument("--root", type=Path, default=ROOT, help="the working folder of the test runs")
    parser.add_argument("--list", action="store_true", help="print the mutants, run nothing")
    parser.add_argument("--fork", action="store_true", help="run each mutant's tests in a child forked after "
                        "the tests' imports (POSIX; several seconds less per mutant)")
    args = parser.parse_args(argv)
    if args.suite:
        jobs = [(args.root / module, list(tests), select) for module, (tests, select) in SUITE.items()
                if args.only in module]
    elif args.files and args.tests:
        jobs = [(file if file.is_absolute() else args.root / file, args.tests, args.select) for file in args.files]
    else:
        parser.error("give FILE... --tests TEST..., or --suite")
    if args.list:
        for file, _, _ in jobs:
            for mutant in mutants(file.read_text()):
                print(f"{file.resolve().relative_to(args.root.resolve())}:{mutant.line}:{mutant.column}  "
                      f"#{mutant.index}  {mutant.change}")
        return 0
    rows = []
    for file, tests, select in jobs:
        outcomes = mutate_file(file, tests, args.root, args.timeout, select, fork=args.fork)
        killed = sum(o.result != "survived" for o in outcomes)
        rows.append((str(file.resolve().relative_to(args.root.resolve())), len(outcomes), killed,
                     sum(o.result == "timeout" for o in outcomes), sum(o.seconds for o in outcomes)))
    print("\n| module | mutants | killed | of which timeouts | survived | score | test time (s) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, total, killed, timeouts, seconds in rows:
        print(f"| {name} | {total} | {killed} | {timeouts} | {total - killed} | {_percent(killed, total)} | "
              f"{seconds:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
