"""Every ``--help`` fits an 80-column terminal, as a user sees it (issue 28, point 7): the
hand-laid-out descriptions and epilogs are fitted to the terminal without losing a word."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mission.cli import COMMANDS, fit_text

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = str(Path(sys.executable).with_name("phireman"))

PAGES = [[], *([name] for name in COMMANDS), ["mission", "new"], ["mission", "show"]]


def _words(text: str) -> list[str]:
    # What fitting may add: shell continuations, a comment's '#', argparse's own wrapping.
    return [w for w in text.split() if w not in ("\\", "#")]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: " ".join(p) or "phireman")
def test_every_help_page_fits_80_columns(page):
    env = dict(os.environ, COLUMNS="80")
    out = subprocess.run(
        [PHIREMAN, *page, "--help"], capture_output=True, text=True, cwd=ROOT, env=env
    )
    assert out.returncode == 0, out.stderr
    wide = [line for line in out.stdout.splitlines() if len(line) > 80]
    assert not wide, f"{len(wide)} line(s) over 80 columns:\n" + "\n".join(wide)
    if len(page) == 1:  # nothing of the command's description is lost on the way
        module = importlib.import_module(f"mission.commands.{COMMANDS[page[0]]}")
        shown = " ".join(_words(out.stdout))
        for word in _words(module.DESCRIPTION):
            assert word in shown, word


TEXT = """\
A paragraph of prose that is rather longer than the narrow terminal it is shown on, in two
lines.

Items:
  report.md      what it holds, explained at such length that it needs a second line and more
                 continued under the text column
  short          fits
  phireman sweep --grid custom --size XS S --attrition 0 1% --method phireman --seeds 10 \\
                 --set n_steps=50 --store quick.sqlite
  phireman sim --seeds 3           # a comment that cannot stay beside its command
"""


@pytest.mark.parametrize("width", [40, 60, 78])
def test_fit_text_keeps_every_word_within_the_width(width):
    out = fit_text(TEXT, width)
    assert all(len(line) <= width for line in out.splitlines()), out
    assert _words(out) == _words(TEXT)
    lines = out.splitlines()
    # definitions continue under their text column; commands continue with a backslash and
    # never between an option and its value
    cont = [line for line in lines if line.startswith(" " * 17) and line.strip()]
    assert cont and all(line[17] != " " for line in cont)
    cmd = [line for line in lines if "phireman sweep" in line][0]
    k = lines.index(cmd)
    while lines[k].endswith(" \\"):
        assert not re.search(r"--size$|--attrition$|--method$", lines[k][:-2]), lines[k]
        k += 1
    assert "--store quick.sqlite" in " ".join(lines[lines.index(cmd) : k + 1])


def test_fit_text_leaves_what_fits_alone():
    assert fit_text(TEXT, 200) == TEXT
