"""The experiment runner: quick runs of every shipped config, resume, worker processes, Dask, the rows journal."""

import csv
import io
import json
import re
import signal
import subprocess
import sys
import time
import warnings

import pytest

from angiohull.cli import main
from angiohull.experiments.config import ConfigError, load_config, shipped_config_names
from angiohull.errors import AngiohullError, InputWarning
from angiohull.experiments.rows import RowsJournal, format_value, parse_value, read_rows, write_atomic
from angiohull.experiments.runner import run_experiment

TIMING = ("time_s", "case_s")


def without_timings(path):
    """The text of a results file without its timing columns (everything else must match byte for byte)."""
    records = list(csv.reader(io.StringIO(path.read_text())))
    keep = [i for i, name in enumerate(records[0]) if name not in TIMING]
    return "\n".join(",".join(record[i] for i in keep) for record in records)


def test_quick_run_of_every_shipped_config(quick_runs):
    for name in shipped_config_names():
        run = quick_runs / name
        config = load_config(name, quick=True)
        header, rows = read_rows(run / "results.csv")
        cases = [json.loads(line) for line in (run / "cases.jsonl").read_text().splitlines()]
        assert [r["case_id"] for r in rows] == list(range(len(cases))), name
        assert [c["case_id"] for c in cases] == list(range(len(cases)))
        assert all(r["status"] in ("ok", "empty") for r in rows), (name, [r["reason"] for r in rows])
        assert load_config(run / "config.yaml") == config  # the resolved config is recorded
        record = json.loads((run / "run.json").read_text())
        assert record["angiohull_version"] and record["mode"] == "quick"
        assert record["cases_done"] == record["cases_total"] == len(cases)
        assert record["invocations"][-1]["cases_run"] == len(cases)
        assert all(c["experiment"] == name and c["tree_seed"] >= 0 for c in cases)  # per-case parameters
        assert (run / "rows.csv").read_text().count("\n") == len(cases) + 1


def test_an_interrupted_run_resumes_to_the_same_results(quick_runs, tmp_path):
    config = load_config("general", quick=True)
    run = tmp_path / "run"
    first = run_experiment(config, run, workers=1, stream=None, max_cases=6)
    assert first.interrupted and first.done == 6
    journal = (run / "rows.csv").read_bytes()
    interim = read_rows(run / "results.csv")[1]
    assert [r["case_id"] for r in interim] == list(range(6))  # the results file is complete for what finished
    with open(run / "rows.csv", "a") as handle:  # a row cut short by a kill during the write
        handle.write("6,simple,6,123,3,AP;LAO")
    assert main(["experiment", "general", "--quick", "-o", str(run), "--workers", "1", "--quiet"]) == 0
    assert (run / "rows.csv").read_bytes().startswith(journal)  # finished rows are never rewritten
    assert without_timings(run / "results.csv") == without_timings(quick_runs / "general" / "results.csv")
    record = json.loads((run / "run.json").read_text())
    assert [i["cases_run"] for i in record["invocations"]] == [6, 9]
    assert [i["interrupted"] for i in record["invocations"]] == [True, False]


def test_a_killed_process_resumes_to_the_same_results(quick_runs, tmp_path):
    """SIGKILL at an arbitrary moment (the worst case: no cleanup at all), then the same command again."""
    run = tmp_path / "run"
    command = [sys.executable, "-m", "angiohull.cli", "experiment", "general", "--quick", "-o", str(run),
               "--workers", "1", "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and process.poll() is None:
            rows = run / "rows.csv"
            if rows.exists() and rows.read_text().count("\n") >= 4:  # header + 3 rows
                break
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait(timeout=30)
    with warnings.catch_warnings():  # a kill during a write leaves a cut-short last line: warned about, ignored
        warnings.simplefilter("ignore", InputWarning)
        done_before = len(read_rows(run / "rows.csv")[1])
    assert 3 <= done_before < 15
    summary = run_experiment(load_config("general", quick=True), run, workers=1, stream=None)
    assert summary.done_before == done_before and summary.done == 15
    assert without_timings(run / "results.csv") == without_timings(quick_runs / "general" / "results.csv")


def test_worker_processes_give_the_same_rows(quick_runs, tmp_path):
    stream = io.StringIO()
    summary = run_experiment(load_config("translation", quick=True), tmp_path / "run", workers=2, stream=stream)
    assert summary.executor == "2 worker processes" and summary.done == 3
    assert without_timings(tmp_path / "run" / "results.csv") == without_timings(quick_runs / "translation" / "results.csv")


def test_a_dask_cluster_gives_the_same_rows(quick_runs, tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://")
        assert main(["experiment", "false_negatives", "--quick", "-o", str(tmp_path / "run"),
                     "--scheduler", address]) == 0
    err = capsys.readouterr().err
    assert f"on Dask scheduler {address}" in err
    assert without_timings(tmp_path / "run" / "results.csv") == \
        without_timings(quick_runs / "false_negatives" / "results.csv")


def test_an_unreachable_scheduler_is_an_error(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    import angiohull.experiments.runner as runner

    monkeypatch.setattr(runner, "DASK_CONNECT_TIMEOUT_S", 1.0)
    code = main(["experiment", "translation", "--quick", "-o", str(tmp_path / "run"), "--scheduler",
                 "tcp://127.0.0.1:9", "--quiet"])
    assert code == 2
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before any work


def test_a_run_directory_refuses_another_config(tmp_path):
    run = tmp_path / "run"
    run_experiment(load_config("translation", quick=True), run, workers=1, stream=None, max_cases=1)
    rows = (run / "rows.csv").read_bytes()
    with pytest.raises(ConfigError, match=r"holds a run of another configuration \(.*mode: 'quick' there, 'full' now"):
        run_experiment(load_config("translation"), run, workers=1, stream=None)
    assert (run / "rows.csv").read_bytes() == rows


def test_progress_and_summary(tmp_path):
    stream = io.StringIO()
    summary = run_experiment(load_config("n_views", quick=True), tmp_path / "run", workers=1, stream=stream)
    text = stream.getvalue()
    assert text.splitlines()[0].startswith("n_views: 45 cases (quick), 0 already done; running 45 on this process")
    assert "n_views: 45/45 cases (100 %)" in text and "cases/s, ETA" in text and "0 failed" in text
    assert summary.text() in text and "complete, 45/45 cases" in summary.text()
    assert str(tmp_path / "run" / "rows.csv") in summary.text()


def test_values_round_trip_exactly():
    for value in (0.1, 1 / 3, 78.17000000000002, 1e-300, -0.0, 12345678901234567):
        text = format_value(value)
        assert parse_value("dice3d" if isinstance(value, float) else "case_id", text) == value
    import numpy as np

    assert format_value(np.float64(0.1)) == "0.1" and format_value(np.int64(7)) == "7"
    assert format_value(float("nan")) == "nan" and np.isnan(parse_value("chamfer_mm", "nan"))


def test_journal_drops_a_partial_line_and_atomic_writes_leave_no_temporaries(tmp_path):
    path = tmp_path / "rows.csv"
    columns = ["case_id", "status", "reason", "dice3d"]
    journal = RowsJournal(path, columns)
    assert journal.open() == []
    journal.append({"case_id": 0, "status": "ok", "reason": "", "dice3d": 80.5})
    journal.append({"case_id": 1, "status": "failed", "reason": "a, b \"quoted\"", "dice3d": float("nan")})
    journal.close()
    with open(path, "a") as handle:
        handle.write("2,ok,,7")
    again = RowsJournal(path, columns)
    rows = again.open()
    again.close()
    assert [r["case_id"] for r in rows] == [0, 1] and rows[1]["reason"] == "a, b \"quoted\""
    assert path.read_text().endswith("\n")
    write_atomic(tmp_path / "x.txt", "hello\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rows.csv", "x.txt"]
    path.write_text(path.read_text().replace("0,ok,", "0,fine,"))  # a status no case gives: refused, not averaged in
    with pytest.raises(AngiohullError, match=r"rows\.csv: line 2, column 'status': 'fine' is not one of ok, empty, "
                                             r"failed, error; the file was changed by hand"):
        read_rows(path, columns)


def test_a_rows_file_cut_short_warns_naming_the_line_it_ignores(tmp_path):
    path = tmp_path / "rows.csv"
    columns = ["case_id", "status", "reason", "dice3d"]
    cut = ("is cut short (no line end: the run was stopped while writing it, or is writing it now); ")
    path.write_text("case_id,status,reason,dice3d\n0,ok,,80.5\n1,ok")  # killed while writing the second row
    with pytest.warns(InputWarning, match=re.escape(f"{path}: line 3 {cut}that row is ignored, and resuming the run "
                                                    f"into this folder runs its case again")):
        assert [r["case_id"] for r in read_rows(path, columns)[1]] == [0]
    path.write_text("case_id,status,reason,dice3d\n0,ok")  # no complete row at all
    with pytest.warns(InputWarning, match=re.escape(f"{path}: line 2 {cut}that row is ignored")):
        assert read_rows(path, columns) == (columns, [])
    path.write_text("case_id,sta")  # killed while writing the header
    with pytest.warns(InputWarning, match=re.escape(f"{path}: line 1 (the header) {cut}the file is read as holding "
                                                    f"no rows")):
        assert read_rows(path, columns) == (columns, [])
    path.write_text("case_id,status,reason,dice3d\n")  # a run that finished no case yet: nothing to warn about
    assert read_rows(path, columns) == (columns, [])
    path.write_text("case_id,status,reason,dice3d\n0,ok,,80.5\n1,ok\n")  # too few cells, but a line end: damaged
    with pytest.raises(AngiohullError, match=re.escape(f"{path}: line 3 has 2 fields, expected 4 (one per column of "
                                                       f"the header); the file was changed by hand or is damaged")):
        read_rows(path, columns)


def test_invocations_that_start_within_the_same_second_are_all_recorded(tmp_path, monkeypatch):
    import angiohull.experiments.runner as runner_module

    class _FrozenClock:  # every invocation "starts" at the same second
        @staticmethod
        def now(tz=None):
            from datetime import datetime

            return datetime(2026, 1, 1, 12, 0, 0, tzinfo=tz)

    monkeypatch.setattr(runner_module, "datetime", _FrozenClock)
    config = load_config("general", quick=True)
    run = tmp_path / "run"
    for _ in range(2):
        run_experiment(config, run, workers=1, stream=None, max_cases=1)
    record = json.loads((run / "run.json").read_text())
    assert [i["cases_run"] for i in record["invocations"]] == [1, 1]
    assert len({i["started"] for i in record["invocations"]}) == 1

