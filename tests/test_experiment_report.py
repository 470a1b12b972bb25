"""The report: every number recomputed from the rows (numpy/scipy oracles here), the paper's values beside them."""

import csv
import json
import math

import numpy as np
import pytest
from scipy import stats

from angiohull.cli import main
from angiohull.experiments.paper import PAPER_RESULTS
from angiohull.experiments.report import find_runs


@pytest.fixture(scope="module")
def report(quick_runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["report", str(quick_runs), "-o", str(out)]) == 0
    return out, json.loads((out / "report.json").read_text()), (out / "report.md").read_text()


def results(run_dir):
    """The results file as columns of floats/strings, read with the csv module (no angiohull code)."""
    with open(run_dir / "results.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    return rows


def floats(rows, column):
    return np.array([float(r[column]) for r in rows])


def oracle_summary(values):
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = len(x)
    mean = x.sum() / n
    std = math.sqrt(((x - mean) ** 2).sum() / (n - 1))
    half = stats.t.ppf(0.975, n - 1) * std / math.sqrt(n)
    return n, mean, std, mean - half, mean + half


def run_of(document, name):
    return next(r for r in document["runs"] if r["name"] == name)


def test_group_tables_are_recomputed_from_the_rows(quick_runs, report):
    _, document, markdown = report
    for name in ("general", "general_clinical"):
        rows = results(quick_runs / name)
        run = run_of(document, name)
        assert [g["label"] for g in run["groups"]] == ["simple", "moderate", "tortuous", "all"]
        for group in run["groups"]:
            subset = rows if group["label"] == "all" else [r for r in rows if r["tortuosity"] == group["label"]]
            assert group["n_cases"] == len(subset)
            for metric in run["metrics"]:
                n, mean, std, low, high = oracle_summary(floats(subset, metric))
                got = group["summaries"][metric]
                assert got["n"] == n
                assert got["mean"] == pytest.approx(mean, rel=1e-12)
                assert got["std"] == pytest.approx(std, rel=1e-10)
                assert (got["ci_low"], got["ci_high"]) == (pytest.approx(low, rel=1e-10), pytest.approx(high, rel=1e-10))
        all_dice = oracle_summary(floats(rows, "dice3d"))
        assert f"{all_dice[1]:.2f} ± {all_dice[2]:.2f} ({all_dice[3]:.2f}–{all_dice[4]:.2f})" in markdown


def test_the_papers_values_stand_beside_ours(quick_runs, report):
    _, document, markdown = report
    for name, table in (("general", "table1"), ("general_clinical", "table2")):
        run = run_of(document, name)
        rows = results(quick_runs / name)
        assert run["paper"]["table"] == table
        published = PAPER_RESULTS[table]
        for entry in run["paper"]["rows"]:
            n, mean, _, low, high = oracle_summary(floats(rows, entry["metric"]))
            assert entry["paper"] == published[entry["metric"]]
            assert entry["difference"] == pytest.approx(mean - published[entry["metric"]], rel=1e-12, abs=1e-12)
            assert entry["paper_in_ci"] == (low <= published[entry["metric"]] <= high)
    for value in ("78.17", "64.24", "0.8307", "78.61", "75.25", "60.39", "0.9992", "73.66"):
        assert value in markdown
    assert PAPER_RESULTS["table1"]["dice3d"] == 78.17 and PAPER_RESULTS["table2"]["chamfer_mm"] == 0.9992


def test_t_tests_match_the_textbook_formulas(quick_runs, report):
    _, document, markdown = report
    rows = results(quick_runs / "general")
    tests = run_of(document, "general")["ttests"]
    assert tests["metric"] == "chamfer_mm"
    pairs = [(t["group_a"], t["group_b"]) for t in tests["tests"]]
    assert pairs == [("simple", "moderate"), ("simple", "tortuous"), ("moderate", "tortuous")]
    for test in tests["tests"]:
        a = floats([r for r in rows if r["tortuosity"] == test["group_a"]], "chamfer_mm")
        b = floats([r for r in rows if r["tortuosity"] == test["group_b"]], "chamfer_mm")
        na, nb = len(a), len(b)
        va, vb = a.var(ddof=1), b.var(ddof=1)
        pooled = ((na - 1) * va + (nb - 1) * vb) / (na + nb - 2)
        t = (a.mean() - b.mean()) / math.sqrt(pooled * (1 / na + 1 / nb))
        p_student = 2 * stats.t.sf(abs(t), na + nb - 2)
        se2 = va / na + vb / nb
        df = se2 ** 2 / ((va / na) ** 2 / (na - 1) + (vb / nb) ** 2 / (nb - 1))
        p_welch = 2 * stats.t.sf(abs((a.mean() - b.mean()) / math.sqrt(se2)), df)
        assert test["t"] == pytest.approx(t, rel=1e-9)
        assert test["p_student"] == pytest.approx(p_student, rel=1e-7)
        assert test["p_welch"] == pytest.approx(p_welch, rel=1e-7)
    assert "not transcribed" in markdown  # Table 3's p-values are not in PAPER_RESULTS


def test_curves_and_correlations_are_recomputed(quick_runs, report):
    _, document, _ = report
    run = run_of(document, "false_positives")
    rows = results(quick_runs / "false_positives")
    ps = sorted({float(r["p"]) for r in rows})
    assert [g["x"] for g in run["groups"]] == ps
    for group in run["groups"]:
        subset = [r for r in rows if float(r["p"]) == group["x"]]
        assert group["summaries"]["dice3d"]["mean"] == pytest.approx(oracle_summary(floats(subset, "dice3d"))[1])
    x, y = floats(rows, "p"), floats(rows, "dice3d")
    rank_r = np.corrcoef(stats.rankdata(x), stats.rankdata(y))[0, 1]
    assert run["correlation"]["dice3d"]["rho"] == pytest.approx(rank_r, rel=1e-9)
    n_views = run_of(document, "n_views")
    assert [g["x"] for g in n_views["groups"]] == list(range(1, 16))
    assert all(g["n_cases"] == 3 for g in n_views["groups"])


def test_figures_and_markdown(report):
    out, document, markdown = report
    names = sorted(r["name"] for r in document["runs"])
    assert len(names) == 8
    for name in names:
        png = out / "figures" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"![{name}](figures/{name}.png)" in markdown
        assert f"## {name}" in markdown
    assert "Quick run" in markdown
    assert "nan" not in (out / "report.json").read_text().lower().replace("nan_", "")


def test_find_runs_and_bad_report_inputs(quick_runs, tmp_path, capsys):
    assert [p.name for p in find_runs([quick_runs])] == sorted(p.name for p in quick_runs.iterdir())
    assert find_runs([quick_runs / "general"]) == [quick_runs / "general"]
    assert main(["report", str(tmp_path), "-o", str(tmp_path / "out")]) == 2
    assert "neither a run directory" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "nowhere"), "-o", str(tmp_path / "out")]) == 2
    assert "nowhere: not found; expected a run directory" in capsys.readouterr().err
    assert main(["report", str(quick_runs / "general"), str(quick_runs / "general"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err  # the folders named
    assert f"two runs of the same experiment (general: {quick_runs / 'general'}, {quick_runs / 'general'})" in err


def test_a_run_whose_configuration_was_edited_or_whose_record_is_damaged_is_reported_with_a_warning(quick_runs,
                                                                                                      tmp_path):
    import shutil

    from angiohull.errors import InputWarning
    from angiohull.experiments.runner import load_run

    run = tmp_path / "translation"
    shutil.copytree(quick_runs / "translation", run)
    record = json.loads((run / "run.json").read_text())
    assert len(record["config_file_sha256"]) == 64
    load_run(run)  # as written: no warning (they are errors here)
    config = run / "config.yaml"
    config.write_text(config.read_text().replace("resolution: 100", "resolution: 40"))
    with pytest.warns(InputWarning, match=r"config\.yaml: edited after the rows were made"):
        assert load_run(run).config.reconstruction.resolution == 40  # the file as it is now, said so
    (run / "run.json").write_text("{ cut")
    with pytest.warns(InputWarning, match=r"run\.json: cannot be read .*goes on without the run's record"):
        assert load_run(run).record == {}


def test_a_run_whose_rows_were_cut_short_or_lost_is_reported_with_a_warning_naming_the_file_and_line(quick_runs,
                                                                                                     tmp_path, capsys):
    import shutil

    run, out = tmp_path / "translation", tmp_path / "out"
    shutil.copytree(quick_runs / "translation", run)
    rows = run / "rows.csv"
    header, first = rows.read_text().splitlines()[:2]
    lost = (f"angiohull: warning: {rows}: holds 0 finished case(s), but run.json recorded 3 when the run last ended: "
            f"rows were lost (the file was cut short, replaced or edited); the report covers the 0 there are; running "
            f"the same experiment into {run} runs the missing cases again\n")
    cut = "is cut short (no line end: the run was stopped while writing it, or is writing it now); "
    for text, warned in [
            (header + "\n" + first[:25], f"{rows}: line 2 {cut}that row is ignored, and resuming the run into this "
                                         f"folder runs its case again\n"),
            (header[:30], f"{rows}: line 1 (the header) {cut}the file is read as holding no rows\n"),
            (header + "\n", None)]:
        rows.write_text(text)
        assert main(["report", str(run), "-o", str(out)]) == 0
        err = capsys.readouterr().err
        assert err == (f"angiohull: warning: {warned}" if warned else "") + lost
        assert json.loads((out / "report.json").read_text())["runs"][0]["cases_done"] == 0
        assert "*Incomplete: 0 of 3 cases finished.*" in (out / "report.md").read_text()
    rows.unlink()
    assert main(["report", str(run), "-o", str(out)]) == 0
    assert capsys.readouterr().err == lost.replace("holds 0 finished case(s)", "is missing")


def test_figure_titles_say_what_ran_and_are_never_cut(report):
    from angiohull.experiments.figures import _wrapped
    from angiohull.experiments.report import figure_title

    _, document, _ = report
    for run in document["runs"]:
        title = figure_title(run)
        assert title.startswith(f"{run['name']}: quick run, {run['cases_done']} of {run['cases_total']} cases")
        assert run["description"] in title  # the full experiment's description, said to be that
    words = ("view 0 (AP) of three perpendicular views shifted by 100 random vectors in [-100, 100)^2 px, one "
             "moderate tree per vector, " * 3).split()
    wrapped = _wrapped(" ".join(words), 8.4)
    assert wrapped.split() == words and "..." not in wrapped and "…" not in wrapped
    assert all(len(line) <= int(8.4 * 72 / (0.55 * 11)) for line in wrapped.splitlines())
    assert len(wrapped.splitlines()) >= 3
