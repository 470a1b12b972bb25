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

FAST = ["-k", "20", "--no-tree", "--no-figure", "--no-viewer", "-q"]


# -- helpers ------------------------------------------------------------------------------------
def disc_study(folder: Path, *, size: int = 64, radius_px: float = 6.0, shift_px: float = 0.0) -> Path:
    """A disc at the image centre in two perpendicular views (a ball at the isocentre); study.yaml path."""
    rr, cc = np.mgrid[0:size, 0:size]
    c = (size - 1) / 2.0
    views = []
    for name, primary in (("ap", 0.0), ("lao90", 90.0)):
        carm = CArmGeometry(primary, 0.0, 1200.0, 800.0, (0.7, 0.7), (size, size))
        dv = shift_px if name == "lao90" else 0.0  # both views see z along their rows: a shift parts the cones
        views.append(View.from_carm(name, (rr - c - dv) ** 2 + (cc - c) ** 2 <= radius_px ** 2, carm))
    points = np.random.default_rng(0).normal(size=(500, 3))
    ball_mm = radius_px * 0.7 * 800.0 / 1200.0
    return save_study(folder, views, ground_truth_mm=ball_mm * points / np.linalg.norm(points, axis=1, keepdims=True))


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


# -- output folders: never over an input, never half-written, no stale files, earlier results kept ----
def _reconstruct(study: Path, out: Path, *extra: str) -> list[str]:
    return ["reconstruct", str(study.parent), "-o", str(out), *FAST, *extra]


def test_output_that_is_a_file_or_under_a_file(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    blocker = tmp_path / "file.txt"
    blocker.write_text("keep me")
    before = snapshot(tmp_path)
    run_fails(capsys, _reconstruct(study, blocker), str(blocker), "is a file")
    run_fails(capsys, _reconstruct(study, blocker / "out"), str(blocker), "is a file, not a folder")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES])
def test_output_folder_that_cannot_be_created(tmp_path, capsys, monkeypatch, code):
    """A read-only file system or a folder without write permission (simulated: the tests may run as root)."""
    import pathlib

    study = disc_study(tmp_path / "study")
    locked = tmp_path / "locked"
    locked.mkdir()
    real = pathlib.Path.mkdir

    def mkdir(self, *args, **kwargs):
        if locked in self.parents:
            raise OSError(code, os.strerror(code), str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    before = snapshot(tmp_path)
    run_fails(capsys, _reconstruct(study, locked / "a" / "out"), str(locked / "a" / "out"), os.strerror(code))
    assert snapshot(tmp_path) == before and not any(locked.iterdir())


@pytest.mark.parametrize("command", ["reconstruct", "report"])
def test_full_disk_leaves_nothing_and_keeps_the_earlier_result(tmp_path, capsys, monkeypatch, command):
    study = disc_study(tmp_path / "study")
    out = tmp_path / "out"
    assert main(_reconstruct(study, out)) == 0
    earlier = snapshot(out)
    before = snapshot(tmp_path)

    def full(path, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    if command == "reconstruct":
        monkeypatch.setattr("angiohull.workflow.write_points_ply", full)
        argv = _reconstruct(study, out, "--overwrite")
    else:  # `report` of a run, into the folder of an earlier report (replaced without --overwrite)
        argv = ["report", str(_finished_run(tmp_path)), "-o", str(tmp_path / "report")]
        assert main(argv) == 0
        out = tmp_path / "report"
        earlier, before = snapshot(out), snapshot(tmp_path)
        monkeypatch.setattr("angiohull.experiments.rows.write_atomic", full)
    capsys.readouterr()
    run_fails(capsys, argv, str(out), "No space left on device", "nothing was written")
    assert snapshot(out) == earlier and snapshot(tmp_path) == before
    assert not [p for p in tmp_path.iterdir() if "angiohull-partial" in p.name]


def test_non_empty_output_needs_overwrite_and_leaves_no_stale_file(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    out = tmp_path / "out"
    assert main(["reconstruct", str(study.parent), "-o", str(out), "-k", "20", "--no-tree", "--no-viewer", "-q"]) == 0
    assert {"centerlines.ply", "figure.png"} <= {p.name for p in out.iterdir()}
    (out / "notes.txt").write_text("mine")
    earlier = snapshot(out)
    run_fails(capsys, _reconstruct(study, out, "--no-centerlines"), str(out), "not empty", "--overwrite", "notes.txt")
    assert snapshot(out) == earlier
    assert main(_reconstruct(study, out, "--no-centerlines", "--overwrite")) == 0
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "vessel.ply"]  # nothing of the earlier run
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_output_over_the_inputs_is_refused_even_with_overwrite(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    (study.parent / "masks" / "ap.png").rename(study.parent / "figure.png")
    study.write_text(study.read_text().replace("masks/ap.png", "figure.png"))
    before = snapshot(tmp_path)
    for out in (study.parent, tmp_path):  # the study folder, and a folder above it
        run_fails(capsys, _reconstruct(study, out, "--overwrite"), "an input of this command")
        assert snapshot(tmp_path) == before


def test_a_failure_late_in_the_run_keeps_the_earlier_result(tmp_path, capsys, monkeypatch):
    study = disc_study(tmp_path / "study")
    out = tmp_path / "out"
    assert main(_reconstruct(study, out)) == 0
    earlier = snapshot(out)

    def broken(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("angiohull.workflow.build_report", broken)
    capsys.readouterr()
    assert main(_reconstruct(study, out, "--overwrite")) == 130  # Ctrl-C
    assert capsys.readouterr().err.strip() == "angiohull reconstruct: interrupted; nothing of this run was written"
    assert snapshot(out) == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "study"]


def test_demo_replaces_its_own_earlier_output(tmp_path, capsys, monkeypatch):
    """`angiohull demo` twice in a row works; another non-empty folder needs --overwrite."""
    monkeypatch.setattr("angiohull.demo.write_demo_study", lambda folder, views=3: disc_study(Path(folder)))
    monkeypatch.setattr("angiohull.viz.reconstruction_figure", lambda path, **kw: Path(path).write_bytes(b"png") and Path(path))
    out = tmp_path / "demo"
    argv = ["demo", "-o", str(out), "-k", "20", "--method", "hull"]
    assert main(argv) == 0
    (out / "qca").mkdir()  # e.g. an analysis a newer demo wrote: still the demo's own
    assert main(argv) == 0
    assert not (out / "qca").exists() and (out / "study" / "study.yaml").is_file()
    report = json.loads((out / "report.json").read_text())
    assert report["study"] == str(out.resolve() / "study")  # where it is, not where it was staged
    capsys.readouterr()
    (out / "notes.txt").write_text("mine")
    run_fails(capsys, argv, "not empty", "--overwrite")
    assert main([*argv, "--overwrite"]) == 0 and not (out / "notes.txt").exists()


def test_other_writing_commands_refuse_to_replace(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    before = snapshot(tmp_path)
    run_fails(capsys, ["synth", str(study.parent), "--seed", "1", "-q"], "not empty", "--overwrite")
    image = tmp_path / "study" / "masks" / "ap.png"
    run_fails(capsys, ["segment", str(image), "-o", str(image)], "an input of this command")
    run_fails(capsys, ["segment", str(image), "-o", str(tmp_path / "study" / "masks" / "lao90.png")], "exists",
              "--overwrite")
    run_fails(capsys, ["segment", str(image), "-o", str(tmp_path / "study")], "is a folder")
    assert snapshot(tmp_path) == before


def _finished_run(tmp_path: Path) -> Path:
    """A run folder whose rows were written by hand (no case is run)."""
    from angiohull.experiments.config import load_config
    from angiohull.experiments.runner import prepare_run_dir

    config = load_config(_config(tmp_path / "c.yaml", design="{type: angles, triplets: 2}"))
    run = prepare_run_dir(config, tmp_path / "run-done")
    (run / "rows.csv").write_text("")
    return run


# -- experiments: full disk, one runner per run directory, workers end with the runner, Dask, rows.csv --
CHEAP = ("generator: {size: 128, pixel_mm: 1.4, rasteriser: exact}\n"
         "reconstruction: {resolution: 20}\n")


def _cheap_config(tmp_path: Path, trees: int = 2) -> Path:
    return _config(tmp_path / "cheap.yaml", design=f"{{type: trees, tortuosity: [simple], trees: {trees}, views: clinical}}",
                   extra=CHEAP)


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc (Linux) to tell the files apart")
def test_experiment_on_a_full_disk_keeps_every_whole_row(tmp_path, capsys, monkeypatch):
    import angiohull.experiments.rows as rows

    config, run = _cheap_config(tmp_path), tmp_path / "run"
    real, calls = os.fsync, []

    def fsync(fd):
        if os.readlink(f"/proc/self/fd/{fd}").endswith("rows.csv"):
            calls.append(fd)
            if len(calls) == 2:  # the header goes through, the first row does not
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(rows.os, "fsync", fsync)
    run_fails(capsys, ["experiment", str(config), "-o", str(run), "--workers", "1", "-q"], str(run),
              "No space left on device", "rows.csv", "resume")
    header = (run / "rows.csv").read_text()
    assert header.count("\n") == 1 and header.startswith("case_id,")  # no row cut short
    monkeypatch.setattr(rows.os, "fsync", real)
    assert main(["experiment", str(config), "-o", str(run), "--workers", "1", "-q"]) == 0  # resumes
    assert (run / "rows.csv").read_text().count("\n") == 3


def test_a_second_runner_on_a_run_directory_is_refused(tmp_path, capsys):
    from angiohull.experiments.config import load_config
    from angiohull.experiments.runner import _RunLock, prepare_run_dir

    config, run = _cheap_config(tmp_path), tmp_path / "run"
    prepare_run_dir(load_config(config), run)
    lock = _RunLock(run).acquire()
    try:
        line = run_fails(capsys, ["experiment", str(config), "-o", str(run), "--workers", "1", "-q"],
                         str(run), "another runner", f"process {os.getpid()} on ", "started ")
    finally:
        lock.release()
    assert "rows.csv" not in {p.name for p in run.iterdir()}, line


def test_a_dead_runner_does_not_hold_the_lock(tmp_path):
    import signal
    import subprocess
    import sys

    from angiohull.experiments.config import load_config
    from angiohull.experiments.runner import LOCK_FILE, prepare_run_dir, run_experiment

    config, run = load_config(_cheap_config(tmp_path)), tmp_path / "run"
    prepare_run_dir(config, run)
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'a+'); "
                               "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)",
                               str(run / LOCK_FILE)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(Exception, match="another runner"):
            run_experiment(config, run, workers=1, stream=None, max_cases=0)
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=10)
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    assert run_experiment(config, run, workers=1, stream=None, max_cases=0).done == 0  # the lock went with it


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:notaport", "tcp://", "127.0.0.1:99999", "http://127.0.0.1:8786",
                                     "tcp://127.0.0.1 :8786", "CLOSED"])
def test_a_bad_or_unreachable_scheduler_fails_fast(tmp_path, capsys, address):
    import socket
    import time

    pytest.importorskip("distributed")
    if address == "CLOSED":  # a local port nothing listens on
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            address = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    config = _cheap_config(tmp_path)
    start = time.monotonic()
    run_fails(capsys, ["experiment", str(config), "-o", str(tmp_path / "run"), "--scheduler", address, "-q"],
              "--scheduler")
    assert time.monotonic() - start < 10
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("cell", ["number", "utf8"])
def test_a_damaged_rows_file_names_file_line_and_column(tmp_path, capsys, cell):
    from angiohull.experiments.config import load_config
    from angiohull.experiments.runner import run_experiment

    config, run = _cheap_config(tmp_path), tmp_path / "run"
    run_experiment(load_config(config), run, workers=1, stream=None, max_cases=1)
    rows = run / "rows.csv"
    header, line = rows.read_text().splitlines()
    column = header.split(",").index("dice3d")
    cells = line.split(",")
    cells[column] = "eighty" if cell == "number" else "\udcff"
    rows.write_bytes((header + "\n" + ",".join(cells) + "\n").encode("utf-8", "surrogateescape"))
    for argv in (["experiment", str(config), "-o", str(run), "--workers", "1", "-q"],
                 ["report", str(run), "-o", str(tmp_path / "report")]):
        run_fails(capsys, argv, str(rows), "line 2", "column 'dice3d'")
    assert not (tmp_path / "report").exists()


def _children(pid: int) -> set[int]:
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.add(int(stat.parent.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not hasattr(os, "fork") or not Path("/proc/self/stat").exists(), reason="needs fork and /proc")
def test_a_worker_ends_when_its_runner_is_killed():
    """The worker set-up alone, in forked processes (a runner and its worker): SIGKILL of the runner
    ends the worker at once. The whole command is tested below (slow: it starts Python three times)."""
    import signal
    import time

    from angiohull.experiments.runner import _worker_init

    read_end, write_end = os.pipe()
    runner = os.fork()
    if runner == 0:  # pragma: no cover - the forked runner
        try:
            worker = os.fork()
            if worker == 0:
                _worker_init(os.getppid())
                os.write(write_end, b"ready\n")
                time.sleep(30)
                os._exit(0)
            time.sleep(30)
        finally:
            os._exit(0)
    os.close(write_end)
    try:
        with os.fdopen(read_end, "rb") as pipe:
            assert pipe.readline() == b"ready\n"
        workers = _children(runner)
        assert len(workers) == 1
        os.kill(runner, signal.SIGKILL)
        os.waitpid(runner, 0)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and any(_alive(pid) for pid in workers):
            time.sleep(0.05)
        assert not [pid for pid in workers if _alive(pid)]
    finally:
        for pid in (runner, *locals().get("workers", ())):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux) to find the worker processes")
@pytest.mark.parametrize("signal_name", ["SIGKILL", "SIGTERM"])
def test_workers_end_with_a_killed_runner(tmp_path, signal_name):
    import signal
    import subprocess
    import sys
    import time

    config, run = _cheap_config(tmp_path, trees=40), tmp_path / "run"
    runner = subprocess.Popen([sys.executable, "-m", "angiohull.cli", "experiment", str(config), "-o", str(run),
                               "--workers", "2", "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        workers: set[int] = set()
        while time.monotonic() < deadline and runner.poll() is None:
            workers = _children(runner.pid)
            rows = run / "rows.csv"
            if len(workers) >= 2 and rows.exists() and rows.read_text().count("\n") >= 2:
                break
            time.sleep(0.1)
        assert runner.poll() is None and len(workers) >= 2
        runner.send_signal(getattr(signal, signal_name))
        runner.wait(timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(pid) for pid in workers):
            time.sleep(0.1)
        assert not [pid for pid in workers if _alive(pid)]
    finally:
        runner.kill()
        runner.wait()
        for pid in workers if "workers" in locals() else ():
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


# -- paths: a study's files stay inside its folder unless it opts in ------------------------------
@pytest.mark.parametrize("field", ["parent", "absolute", "symlink", "ground_truth"])
def test_paths_outside_the_study_folder(tmp_path, capsys, field):
    study = disc_study(tmp_path / "study")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    mask = study.parent / "masks" / "ap.png"
    text = study.read_text()
    if field == "ground_truth":
        (study.parent / "gt.npy").rename(elsewhere / "gt.npy")
        text, name, needle = text.replace("ground_truth: gt.npy", "ground_truth: ../elsewhere/gt.npy"), "ground_truth", "'../elsewhere/gt.npy'"
    elif field == "symlink":
        mask.rename(elsewhere / "ap.png")
        mask.symlink_to(elsewhere / "ap.png")
        name, needle = "views[0].mask", str(elsewhere / "ap.png")
    else:
        mask.rename(elsewhere / "ap.png")
        new = "../elsewhere/ap.png" if field == "parent" else str(elsewhere / "ap.png")
        text, name, needle = text.replace("masks/ap.png", new), "views[0].mask", repr(new)
    study.write_text(text)
    before = snapshot(tmp_path)
    line = run_fails(capsys, ["evaluate", str(study.parent), "-k", "20", "--method", "hull"], f"{study}: {name}: ",
                     needle, "allow_outside_paths: true")
    assert "outside" in line or "leads out" in line or "absolute" in line
    assert snapshot(tmp_path) == before
    study.write_text(text + "allow_outside_paths: true\n")  # the opt-in
    assert main(["evaluate", str(study.parent), "-k", "20", "--method", "hull", "--json"]) == 0


# -- accepted silently before: now a warning (legal but suspicious) or an error ----------------------
def warning_lines(err: str) -> list[str]:
    assert "Traceback" not in err, err
    return [line for line in err.splitlines() if line.startswith("angiohull: warning: ")]


def test_a_mask_of_all_ones_is_a_warning(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    write_mask(study.parent / "masks" / "lao90.png", np.ones((64, 64), bool))
    assert main(["evaluate", str(study.parent), "-k", "20", "--method", "hull", "--json"]) == 0
    # the mask's own warning, and (the hull of both views covers little of it) the views' disagreement
    [line] = [w for w in warning_lines(capsys.readouterr().err) if "views disagree" not in w]
    assert f"{study}: views[1].mask: view 'lao90'" in line and "every pixel is vessel" in line and "inverted" in line


def test_a_tiny_mask_is_a_warning(tmp_path):
    from angiohull.errors import InputWarning
    from angiohull.study import load_study

    views = [View.from_carm("tiny", np.array([[1, 0], [0, 0]], bool), CArmGeometry(0.0, 0.0, 1200.0, 800.0, (30.0, 30.0), (2, 2))),
             View.from_carm("big", np.eye(64, dtype=bool), CArmGeometry(90.0, 0.0, 1200.0, 800.0, (0.7, 0.7), (64, 64)))]
    study = save_study(tmp_path / "study", views)
    with pytest.warns(InputWarning, match=r"views\[0\]\.mask: view 'tiny' .*only 2 x 2 pixels"):
        load_study(study)


def test_two_views_that_share_nothing_are_an_error(tmp_path, capsys):
    study = disc_study(tmp_path / "study", shift_px=25.0)  # the two cones miss each other
    assert main(_reconstruct(study, tmp_path / "out")) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip() and not line.startswith("[")]
    # the two masks' epipolar planes say by how much (the disc moved 25 px across the epipolar lines), then the error
    assert len(lines) == 2 and lines[0].startswith("angiohull: warning: the two views' masks cover the same epipolar "
                                                   "planes only with lao90 moved by 25.0 px")
    assert lines[1].startswith("angiohull reconstruct: error: ") and "empty" in lines[1] and "lao90" in lines[1]
    assert not (tmp_path / "out").exists()


def test_an_empty_ground_truth_is_an_error(tmp_path, capsys):
    study = disc_study(tmp_path / "study")
    np.save(study.parent / "gt.npy", np.empty((0, 3)))
    run_fails(capsys, ["evaluate", str(study.parent), "-k", "20", "--method", "hull"], f"{study}: ground_truth: ",
              "gt.npy", "no points")


@pytest.mark.parametrize("count, outcome", [(20, "warning"), (60, "error")])
def test_corruptions_that_erase_a_view(tmp_path, capsys, count, outcome):
    argv = ["synth", str(tmp_path / "s"), "--size", "128", "--pixel-mm", "1.4", "--seed", "1", "--corrupt",
            f"missing={count}", "-q"]
    if outcome == "error":
        run_fails(capsys, argv, "erased all", "every view needs some left")
        assert not (tmp_path / "s").exists()
    else:
        assert main(argv) == 0
        lines = warning_lines(capsys.readouterr().err)
        assert lines and all("--corrupt: view " in line and "vessel pixels" in line for line in lines)


# DICOM headers: the file and the tag are named
def _xa(tmp_path: Path, name: str = "a.dcm", **extra) -> Path:
    from _dicom_files import write_xa

    image = np.full((64, 64), 180, np.uint8)
    image[28:36, :] = 60  # a dark band: a vessel
    return write_xa(tmp_path / name, image, **extra)


@pytest.mark.parametrize("case, needles", [
    ("ct", ("Modality (0008,0060) is 'CT'", "contradicts")),
    ("flip", ("FieldOfViewHorizontalFlip (0018,7034) is YES", "mirrored")),
    ("rotation", ("FieldOfViewRotation (0018,7032) is 90 degrees", "rotated")),
    ("vr", ("PositionerPrimaryAngle (0018,1510)", "damaged")),
    ("big_endian", ("TransferSyntaxUID (0002,0010)", "mislabelled")),
])
def test_bad_dicom_headers_are_errors(tmp_path, capsys, case, needles):
    extra = {"ct": {"modality": "CT"}, "flip": {"FieldOfViewHorizontalFlip": "YES"},
             "rotation": {"FieldOfViewRotation": 90}}.get(case, {})
    path = _xa(tmp_path, **extra)
    data = path.read_bytes()
    if case == "vr":
        at = data.find(b"\x18\x00\x10\x15DS")
        path.write_bytes(data[:at + 4] + b"XX" + data[at + 6:])
    elif case == "big_endian":
        path.write_bytes(data.replace(b"1.2.840.10008.1.2.1\x00", b"1.2.840.10008.1.2.2\x00"))
    run_fails(capsys, ["dicom-info", str(path)], str(path), *needles)


@pytest.mark.parametrize("case", ["ffs", "implicit_label", "padding"])
def test_suspicious_dicom_files_are_warnings(tmp_path, capsys, case):
    import pydicom

    path = _xa(tmp_path, **({"PatientPosition": "FFS"} if case == "ffs" else {}))
    if case == "implicit_label":  # says Implicit VR Little Endian, holds Explicit VR
        path.write_bytes(path.read_bytes().replace(b"1.2.840.10008.1.2.1\x00", b"1.2.840.10008.1.2\x00\x00\x00"))
    elif case == "padding":  # pixel data longer than the image
        ds = pydicom.dcmread(path)
        ds.PixelData = ds.PixelData + bytes(100)
        ds.save_as(path)
    code = main(["segment", str(path), "-o", str(tmp_path / "m.png"), "--min-object-px", "10", "--no-collimator"])
    err = capsys.readouterr().err
    lines = warning_lines(err)
    assert lines and all(str(path) in line for line in lines), err
    expected = {"ffs": "PatientPosition (0018,5100) is 'FFS'", "implicit_label": "TransferSyntaxUID (0002,0010)",
                "padding": "PixelData (7FE0,0010)"}[case]
    assert any(expected in line for line in lines), lines
    assert code in (0, 2)  # whether this toy image segments is not the point


def test_an_experiment_into_a_folder_that_holds_no_run_is_refused(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "thesis.tex").write_text("mine")
    run_fails(capsys, ["experiment", str(_cheap_config(tmp_path)), "-o", str(run), "--workers", "1", "-q"],
              str(run), "not empty", "thesis.tex")
    assert sorted(p.name for p in run.iterdir()) == ["thesis.tex"]
