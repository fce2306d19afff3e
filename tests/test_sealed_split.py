"""The sealed test split (configs/seeds.yaml ``evaluation.*.test``): only the final evaluation of a
frozen policy (``python -m ahrm_stack.evaluate ... --split test``, and the experiment's final table
through it) reads it. Training, studies and benchmarks cannot: their source never names it, the one
function that returns it refuses every other caller and any caller while a training runs, and a
short training (warm start, reverse curriculum, interim and final evaluations) watched by a spy
never draws a test seed."""

import ast
import json
from pathlib import Path

import pytest
import yaml

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.evaluation import evaluate
from ahrm_stack.evaluate import main as evaluate_cli
from ahrm_stack.seeds import SealedSplitError, evaluation_range, sealed, seed_table

ROOT = Path(__file__).resolve().parents[1]
SCANNED = [ROOT / "ahrm_stack" / "train.py", *sorted((ROOT / "ahrm_stack" / "learning").rglob("*.py")),
           *sorted((ROOT / "studies").rglob("*.py")), *sorted((ROOT / "benchmarks").rglob("*.py"))]


def _test_ranges():
    return [s.test for s in seed_table().evaluation.values()]


def _names_the_test_split(source: str, filename: str = "<source>") -> list[str]:
    """Every place in ``source`` that could reach the test split: a string "test" (a split
    argument, ``--split test``), a string naming the split flag, an attribute ``.test`` (a
    SplitRanges' test range) or the disjointness helper ``every_range``."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and (
                node.value.strip() == "test" or "--split" in node.value or "split=test" in node.value):
            found.append(f"{filename}:{node.lineno}: {node.value!r}")
        elif isinstance(node, ast.Attribute) and node.attr in ("test", "every_range"):
            found.append(f"{filename}:{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.Name) and node.id == "every_range":
            found.append(f"{filename}:{node.lineno}: every_range")
    return found


def test_the_scan_catches_each_way_to_the_test_split():
    for snippet in ('evaluate(run, 40, split="test")', 'subprocess.call(["x", "--split", "test"])',
                    'seed_table().evaluation["heldout"].test.start', "seed_table().every_range()",
                    'evaluation_range("run", "test")'):
        assert _names_the_test_split(snippet), snippet
    assert not _names_the_test_split('evaluation_range("run", "validation")')


def test_no_training_study_or_benchmark_source_names_the_test_split():
    assert len(SCANNED) > 20  # train.py, learning/, studies/, benchmarks/ were found
    found = [hit for path in SCANNED
             for hit in _names_the_test_split(path.read_text(), str(path.relative_to(ROOT)))]
    assert not found, found


# tools/ that name the test split, each for a reason; every other tool is scanned as studies are
TOOLS_THAT_NAME_IT = {
    "tools/backfill_test_ledger.py": "names each set's test start to find the set of an old output",
    "tools/reanalysis_rows.sh": "the clone-only rows' and the capped teacher's one test read each (ledger)",
    "tools/default_seeds.sh": "the default seeds' final evaluation (each read recorded in the ledger)",
    "tools/paper_row.py": "reads the committed outputs of the paper row's one final evaluation",
    "tools/results_headlines.py": "reads the committed outputs of the final evaluations",
    "tools/import_graph.py": "ast.If.test (an attribute of Python's syntax tree, not a split)",
    "tools/mutate.py": "ast.If.test (an attribute of Python's syntax tree, not a split)",
}


def test_no_tool_names_the_test_split_but_the_listed_ones():
    tools = sorted(path for path in (ROOT / "tools").rglob("*") if path.is_file() and path.suffix != ".pyc")
    assert len(tools) >= 5
    found = []
    for path in tools:
        name, text = str(path.relative_to(ROOT)), path.read_text(errors="replace")
        hits = (_names_the_test_split(text, name) if path.suffix == ".py" else
                [name] if any(w in text for w in ("--split test", "split=test", "split test")) else [])
        if hits and name not in TOOLS_THAT_NAME_IT:
            found += hits
    assert not found, found
    assert all((ROOT / name).is_file() for name in TOOLS_THAT_NAME_IT)  # no stale exemption


def test_no_script_in_studies_or_benchmarks_names_the_test_split():
    """Shell and other non-Python files there too (a registered row's final evaluation lives in
    tools/, e.g. tools/default_seeds.sh)."""
    scripts = [path for folder in ("studies", "benchmarks") for path in sorted((ROOT / folder).rglob("*"))
               if path.is_file() and path.suffix not in (".py", ".pyc")]
    found = [str(path.relative_to(ROOT)) for path in scripts
             if any(word in path.read_text(errors="replace") for word in ("--split test", "split=test", "split test"))]
    assert not found, found


def test_the_one_function_refuses_the_test_split_to_other_callers():
    assert evaluation_range("heldout").start == seed_table().evaluation["heldout"].validation.start
    with pytest.raises(SealedSplitError, match="the test split is sealed: .* not .*test_sealed_split"):
        evaluation_range("heldout", "test")
    with pytest.raises(SealedSplitError):
        evaluation_range("run", "test")
    with pytest.raises(Exception, match="split must be one of"):
        evaluation_range("run", "train")  # type: ignore[arg-type]
    with pytest.raises(Exception, match="no evaluation seeds for 'nowhere'"):
        evaluation_range("nowhere")


def test_the_final_evaluation_reads_the_test_split_and_names_it(tmp_path, capsys):
    assert evaluate_cli(["--policy", "scripted", "--episodes", "1", "--layout", "default", "--split", "test",
                         "--out", str(tmp_path / "cli")]) == 0
    result = json.loads((tmp_path / "cli" / "evaluation.json").read_text())
    assert result["split"] == "test"
    assert result["seed_offset"] == seed_table().evaluation["default"].test.start
    assert "default layout, test split" in capsys.readouterr().out
    validation = evaluate(None, 1, layout="default", out=tmp_path / "validation", quiet=True)
    assert validation["split"] == "validation"
    assert validation["seed_offset"] == seed_table().evaluation["default"].validation.start
    with pytest.raises(SystemExit) as exit_:  # argparse: one line naming the choices
        evaluate_cli(["--policy", "scripted", "--split", "train"])
    assert exit_.value.code == 2
    assert "--split: invalid choice: 'train'" in capsys.readouterr().err


def test_the_test_split_is_sealed_while_a_training_runs(tmp_path, capsys):
    with sealed():
        with pytest.raises(SealedSplitError, match="while a training runs"):
            evaluate(None, 1, layout="default", out=tmp_path / "no", quiet=True, split="test")
    assert not (tmp_path / "no").exists()  # refused before anything was written
    with sealed():
        assert evaluate_cli(["--policy", "scripted", "--episodes", "1", "--split", "test",
                             "--out", str(tmp_path / "cli")]) == 2
    assert "the test split is sealed while a training runs" in capsys.readouterr().err


@pytest.fixture
def seed_spy(monkeypatch):
    """Every seed any TaskRunner (training, demonstrations, curriculum, evaluation) is given."""
    drawn: list[int] = []
    init, reseed = TaskRunner.__init__, TaskRunner.seed

    def spy_init(self, task, seed=None, safety=None):
        if seed is not None:
            drawn.append(int(seed))
        init(self, task, seed, safety)

    def spy_seed(self, seed):
        drawn.append(int(seed))
        reseed(self, seed)

    monkeypatch.setattr(TaskRunner, "__init__", spy_init)
    monkeypatch.setattr(TaskRunner, "seed", spy_seed)
    return drawn


def test_a_short_training_never_draws_a_test_seed(tmp_path, seed_spy):
    """Warm start (demonstrations), the reverse curriculum's scripted episodes, interim evaluations
    and the final one of ``python -m ahrm_stack.train``: every seed the simulator is given lies
    outside every test range; the spy sees the validation seeds, so it would see test seeds too
    (the last assertion: the final evaluation with --split test shows up in it)."""
    from ahrm_stack.train import main as train

    run = tmp_path / "run"
    assert train(["ppo.hidden_sizes=[16]", "ppo.frames_per_batch=128", "task.episode.duration=10",
                  "train.demo_episodes=3", "train.bc_epochs=1", "train.start_curriculum=scripted_states",
                  "train.curriculum_states=2", "train.episodes=2", "train.eval_every=1", "train.eval_episodes=1",
                  "--run-dir", str(run), "--no-progress"]) == 0
    table = seed_table()
    tests = _test_ranges()
    assert seed_spy and not [s for s in seed_spy if any(s in r for r in tests)]
    for used in (table["training"], table["demonstrations"], table["start_states"],
                 table.evaluation["run"].validation):
        assert any(s in used for s in seed_spy), used.name
    assert yaml.safe_load((run / "evaluation.yaml").read_text())["split"] == "validation"
    seed_spy.clear()
    assert evaluate_cli([str(run), "--episodes", "1", "--split", "test"]) == 0  # the frozen policy, after
    assert any(s in table.evaluation["run"].test for s in seed_spy)
    assert json.loads((run / "test" / "evaluation.json").read_text())["split"] == "test"


def test_the_command_line_reads_the_test_split_and_a_script_cannot(tmp_path):
    """``python -m ahrm_stack.evaluate --split test`` runs as ``__main__``; it is let in by its
    module spec, while any other script (``__main__`` without that spec) is refused."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run([sys.executable, "-m", "ahrm_stack.evaluate", "--policy", "scripted", "--episodes", "1",
                           "--split", "test", "--out", str(tmp_path / "out")], cwd=root, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-500:]
    assert "test split" in done.stdout
    script = tmp_path / "peek.py"
    script.write_text("from ahrm_stack.seeds import evaluation_range\nevaluation_range('run', 'test')\n")
    peek = subprocess.run([sys.executable, str(script)], cwd=root, env=env, capture_output=True, text=True,
                          timeout=120)
    assert peek.returncode != 0 and "sealed" in peek.stderr
