"""The README's commands run as written, in order, on a fresh folder.

The README promises that every command it shows runs as written. The fast test
parses each one with the real command line; the slow one runs the whole block in
order in a temporary folder (``scenarios/`` linked to this repository's), each
command on what the ones before it made. CI runs it reduced: the Monte Carlo and
GSA sizes of the fdi commands are cut (:data:`REDUCED`), which changes how long
they take, not which code runs. ``SAMFDI_README_FULL=1`` runs the block exactly as
written (about half an hour on 2 cores).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sam
from sam.constants import LPM
from samfdi.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: option -> the value CI runs it with, replacing the README's; per subcommand, options added when
#: the subcommand has them (their defaults are the expensive part)
REDUCED = {"--runs": "5", "--n": "128", "--healthy": "2", "--per-case": "1"}
ADDED = {("fdi", "thresholds"): {"--n-leak": "4", "--n-nuisance": "8"},
         ("gsa", "reconstruct"): {"--n": "128", "--bootstrap": "40"}}


def readme_commands() -> list[list[str]]:
    """The command lines of the README's "Commands" block, comments removed, as argument lists."""
    text = README.read_text()
    section = text[text.index("## Commands"):]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [args for args in (shlex.split(line, comments=True) for line in block.splitlines()) if args]


def test_the_readme_starts_with_the_two_lines():
    lines = README.read_text().splitlines()
    assert 'python3 -m venv .venv && . .venv/bin/activate && pip install -e . && samfdi demo' in lines
    assert ('python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && python -m pytest -q'
            in lines)


@pytest.mark.parametrize("args", readme_commands(), ids=lambda a: " ".join(a[1:4]))
def test_every_readme_command_parses_and_names_shipped_files(args):
    """No placeholders ([--n N], DIR): each line is a command the parser accepts as it stands."""
    assert args[0] == "samfdi"
    build_parser().parse_args(args[1:])
    for arg in args:
        if arg.startswith("scenarios/"):
            assert (ROOT / arg).exists(), arg


def _subcommand_options(path: tuple[str, ...]) -> set[str]:
    parser = build_parser()
    for name in path:
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        parser = sub.choices[name]
    return {opt for a in parser._actions for opt in a.option_strings}


def reduced(args: list[str]) -> list[str]:
    out = list(args)
    for i, arg in enumerate(out[:-1]):
        if arg in REDUCED:
            out[i + 1] = REDUCED[arg]
    path = tuple(a for a in out[1:3] if not a.startswith("-"))
    for option, value in ADDED.get(path, {}).items():
        if option in _subcommand_options(path) and option not in out:
            out += [option, value]
    return out


@pytest.mark.slow
def test_the_readme_commands_run_in_order(tmp_path):
    (tmp_path / "scenarios").symlink_to(ROOT / "scenarios")
    full = os.environ.get("SAMFDI_README_FULL") == "1"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    printed = {}
    for args in readme_commands():
        run = args if full else reduced(args)
        done = subprocess.run([sys.executable, "-m", "samfdi", *run[1:]], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=3600)
        assert done.returncode == 0, f"{' '.join(args)} failed:\n{done.stderr[-2000:]}"
        assert "Traceback" not in done.stderr, done.stderr
        printed[args[1]] = printed.get(args[1], "") + done.stdout
    check_demo(tmp_path / "samfdi-demo", printed["demo"])


def check_demo(out: Path, printed: str) -> None:
    """What ``samfdi demo`` (no --out: a folder samfdi-demo here) writes and says, checked inside
    the README run rather than by a second demo of its own."""
    assert "samfdi demo: writing to samfdi-demo/" in printed and printed.rstrip().endswith("done: samfdi-demo/")
    assert (out / "healthy_vs_leak.png").exists()
    healthy, leak = sam.read_recording(out / "healthy.csv"), sam.read_recording(out / "extA_leak.csv")
    assert leak.truth["true_K_extA"][-1] == pytest.approx(0.5 * LPM / np.sqrt(10e6))  # 0.5 L/min at 10 MPa
    assert leak.truth["true_pA"][-1] < healthy.truth["true_pA"][-1]
    # the sensitivity ranking is stated only as far as the 95 % intervals separate it (N = 512):
    # on the default plant the BT pair is tied and the PA pair separated
    line = next(ln for ln in printed.splitlines() if "2. sensitivity (paper_parameters" in ln)
    assert "p_A: dp_N_BT ≈ Q_N_BT (tied within the 95 % intervals) > dp_N_PA > Q_N_PA;" in line
    for stage, written in (("3. fault replay", "fdi_replay/diagnosis.json"), ("4. mismatch", "mismatch/report.md")):
        assert any(ln.strip().startswith(stage) for ln in printed.splitlines()), stage
        assert (out / written).exists(), written
