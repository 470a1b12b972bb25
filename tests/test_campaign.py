"""Bad input, faults and interruptions through the command line (issue 24's campaign).

Every case ends in exit status 2 and exactly one line ``angiohull CMD: error: ...`` on stderr
naming the file, field or option (no traceback), or, for legal but suspicious input, a one-line
``angiohull: warning: ...``; no file outside the output folder is touched and no earlier result
is lost. Inputs are tiny (64 x 64 masks, K = 20) so that the whole file runs in seconds.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest

from angiohull.cli import main
from angiohull.geometry import CArmGeometry
from angiohull.io import write_mask
from angiohull.study import View, save_study

FAST = ["-k", "20", "--no-tree", "--no-figure", "-q"]


# -- helpers ------------------------------------------------------------------------------------
def disc_study(folder: Path, *, size: int = 64, radius_px: float = 6.0, shift_px: float = 0.0) -> Path:
    """A disc at the image centre in two perpendicular views (a ball at the isocentre); study.yaml path."""
    rr, cc = np.mgrid[0:size, 0:size]
    c = (size - 1) / 2.0
    views = []
    for name, primary in (("ap", 0.0), ("lao90", 90.0)):
        carm = CArmGeometry(primary, 0.0, 1200.0, 800.0, (0.7, 0.7), (size, size))
        dx = shift_px if name == "lao90" else 0.0
        views.append(View.from_carm(name, (rr - c) ** 2 + (cc - c - dx) ** 2 <= radius_px ** 2, carm))
    return save_study(folder, views)


def snapshot(root: Path, *, skip: Path | None = None) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` (but ``skip``) with its size and modification time."""
    found = {}
    for path in sorted(root.rglob("*")):
        if skip is not None and (path == skip or skip in path.parents):
            continue
        if path.is_file():
            stat = path.stat()
            found[str(path.relative_to(root))] = (stat.st_size, stat.st_mtime_ns)
    return found


def error_line(capsys, command: str, *needles: str) -> str:
    """The one error line on stderr (progress lines ``[ t s] ...`` aside), checked for ``needles``."""
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("[")]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"angiohull {command}: error: "), lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def run_fails(capsys, argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    return error_line(capsys, argv[0], *needles)


# -- YAML: one safe loader for every file ---------------------------------------------------------
def _study_text(study: Path) -> str:
    return study.read_text(encoding="utf-8")


@pytest.mark.parametrize("case", ["duplicate", "deep", "bomb", "recursive", "utf8"])
def test_bad_study_yaml_is_one_line(tmp_path, capsys, case):
    study = disc_study(tmp_path / "study")
    text = _study_text(study)
    if case == "duplicate":
        study.write_text(text + "angiohull: 1\n", encoding="utf-8")
        needles = ("duplicate key 'angiohull'", "line", "study.yaml")
    elif case == "deep":
        study.write_text(text + "extra: " + "[" * 50_000 + "]" * 50_000 + "\n", encoding="utf-8")
        needles = ("nested more than 64 levels",)
    elif case == "bomb":
        lines = ['l0: &l0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
        lines += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 9)]
        bomb = "\n".join(lines) + "\n"
        study.write_text(bomb + text.replace("- name: ap", "- name: *l8"), encoding="utf-8")
        needles = ("aliases", "1,000,000")
    elif case == "recursive":
        study.write_text(text.replace("- name: ap", "- name: &me [*me]"), encoding="utf-8")
        needles = ("recursive",)
    else:
        study.write_bytes(text.encode() + b"# caf\xe9\n")
        needles = ("not UTF-8", "0xe9")
    out = tmp_path / "out"
    run_fails(capsys, ["reconstruct", str(study.parent), "-o", str(out), *FAST], str(study), *needles)
    assert not out.exists()


def test_duplicate_key_names_key_and_lines(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    text = _study_text(study).replace("    sid_mm: 1200.0\n", "    sid_mm: 1200.0\n    sid_mm: 1000.0\n", 1)
    study.write_text(text, encoding="utf-8")
    line = run_fails(capsys, ["evaluate", str(study.parent)], "duplicate key 'sid_mm'")
    assert line.count("line ") == 2


# -- sizes and thresholds: upper bounds with the reason ---------------------------------------------
@pytest.mark.parametrize("threshold", ["300", "1e5", "1e9", "inf", "nan", "-1"])
@pytest.mark.parametrize("command", ["reconstruct", "evaluate", "demo"])
def test_threshold_bound(tmp_path, capsys, command, threshold):
    study = disc_study(tmp_path / "study")
    argv = {"reconstruct": ["reconstruct", str(study.parent), "-o", str(tmp_path / "out")],
            "evaluate": ["evaluate", str(study.parent)], "demo": ["demo", "-o", str(tmp_path / "out")]}[command]
    before = snapshot(tmp_path)
    needles = ("--threshold", "at most 32 px") if threshold in ("300", "1e5", "1e9") else ("--threshold",)
    run_fails(capsys, [*argv, "--threshold", threshold], *needles)
    assert snapshot(tmp_path) == before


def test_resolution_bound(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    run_fails(capsys, ["reconstruct", str(study.parent), "-o", str(tmp_path / "out"), "-k", "100000"],
              "--resolution", "1024")
    assert not (tmp_path / "out").exists()


def test_synth_size_bound(tmp_path, capsys):
    run_fails(capsys, ["synth", str(tmp_path / "s"), "--size", "100000", "--seed", "1"], "--size", "8192")
    assert not (tmp_path / "s").exists()


def _config(path: Path, *, design: str = "{type: trees, tortuosity: [simple], trees: 2, views: clinical}",
            extra: str = "") -> Path:
    path.write_text(f"angiohull_experiment: 1\nname: tiny\nseed: 3\ndesign: {design}\nmetrics: [dice3d]\n{extra}",
                    encoding="utf-8")
    return path


@pytest.mark.parametrize("case", ["cases", "angles", "min_views", "utf8", "threshold", "duplicate"])
def test_bad_experiment_config(tmp_path, capsys, case):
    design, extra = "{type: trees, tortuosity: [simple], trees: 2, views: clinical}", ""
    if case == "cases":
        design = ("{type: trees, tortuosity: [simple, moderate, tortuous], trees: 1000000, views: clinical, sweep: "
                  "{corruption: fp, values: {grid: {start: 0, stop: 0.1, count: 100000}}}}")
        needles = ("design", "300,000,000,000 cases", "at most 1,000,000")
    elif case == "angles":
        design = '{type: trees, tortuosity: [simple], trees: 2, views: "RAO 720; LAO 30"}'
        needles = ("design.views", "RAO 720", "180 degrees")
    elif case == "min_views":
        extra = "reconstruction: {min_views: 4}\n"
        needles = ("reconstruction.min_views", "got 4", "at most 3")
    elif case == "threshold":
        extra = "reconstruction: {threshold_px: 1e5}\n"
        needles = ("reconstruction.threshold_px", "at most 32 px")
    elif case == "duplicate":
        extra = "seed: 4\n"
        needles = ("duplicate key 'seed'", "line 3", "line 6")
    else:
        needles = ("not UTF-8", "line 2")
    config = _config(tmp_path / "c.yaml", design=design, extra=extra)
    if case == "utf8":
        config.write_bytes(config.read_bytes().replace(b"name: tiny", b"name: t\xffny"))
    run_fails(capsys, ["experiment", str(config), "-o", str(tmp_path / "run"), "--workers", "1", "-q"],
              str(config), *needles)
    assert not (tmp_path / "run").exists()
