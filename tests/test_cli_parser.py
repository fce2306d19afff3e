"""One argument parser for every entry point (ahrm_stack.cli.Parser): an unknown flag is one line on
stderr naming it, exit status 2, never argparse's usage block or a traceback."""

import importlib

import pytest

ENTRY_POINTS = ("train", "evaluate", "experiment", "robustness", "demo", "deploy.cli", "run_config",
                "test_ledger", "perception.calibrate", "perception.camera_check", "perception.detection_range")


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_an_unknown_flag_is_one_line(name, capsys):
    main = importlib.import_module(f"ahrm_stack.{name}").main
    with pytest.raises(SystemExit) as exit_:
        main(["--no-such-flag"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err, err
    assert "--no-such-flag" in err or "arguments are required" in err, err  # argparse names the first problem


def test_every_entry_point_uses_the_one_parser():
    """No module of the package builds its own argparse.ArgumentParser."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    own = [str(p.relative_to(root)) for folder in ("ahrm_stack",) for p in (root / folder).rglob("*.py")
           if "argparse.ArgumentParser(" in p.read_text() and p.name != "cli.py"]
    assert not own, own
