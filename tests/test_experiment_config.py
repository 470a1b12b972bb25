"""Experiment configurations: the shipped ones load at the paper's sizes; bad ones are rejected, naming the field."""

import pytest
import yaml

from angiohull.cli import main
from angiohull.experiments.cases import expand_cases
from angiohull.experiments.config import (ConfigError, config_from_dict, config_to_dict, load_config,
                                          shipped_config_names, shipped_config_path)

PAPER_SIZES = {"general": 600, "general_clinical": 600, "translation": 100, "scaling": 150,
               "false_positives": 1100, "false_negatives": 1000, "n_views": 1500, "angles": 150}


def test_every_study_of_the_paper_ships_at_the_papers_size():
    assert shipped_config_names() == sorted(PAPER_SIZES)
    for name, size in PAPER_SIZES.items():
        config = load_config(name)
        assert config.name == name and config.mode == "full"
        assert len(expand_cases(config)) == size, name
        assert config.reconstruction.model_dump() == {"engine": "octree", "resolution": 100, "threshold_px": 1.0,
                                                      "preset": "paper", "calibrate": False, "calibrate_scale": False,
                                                      "min_views": None, "method": "hull"}
        assert config.generator.rasteriser == "paper"
        assert shipped_config_path(name).read_text().startswith("#"), "each file says what it reproduces"


def test_quick_keeps_the_shape_and_shrinks_the_size():
    for name in shipped_config_names():
        full, quick = load_config(name), load_config(name, quick=True)
        assert quick.mode == "quick"
        assert 3 <= len(expand_cases(quick)) < len(expand_cases(full)) / 10
        if full.design.type == "trees":
            assert quick.design.tortuosity == full.design.tortuosity
            assert (quick.design.sweep is None) == (full.design.sweep is None)
        if full.design.type == "n_views":
            assert quick.design.n_views == full.design.n_views  # N = 1..15 kept
        assert quick.quick_version() is quick  # --quick on a quick config is a no-op


def _write(tmp_path, data, name="bad.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _general():
    return config_to_dict(load_config("general"))


def _edit(data, dotted, value):
    keys = dotted.split(".")
    node = data
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value
    return data


@pytest.mark.parametrize("base, field, value, expected", [
    ("general", "design.trees_per_group", 5, "bad.yaml: design.trees_per_group: unknown key; expected one of: type, tortuosity, trees"),
    ("general", "generator.colour", "red", "bad.yaml: generator.colour: unknown key"),
    ("general", "seed", "abc", "bad.yaml: seed: got 'abc' (str); expected a valid integer"),
    ("general", "design.trees", 0, "bad.yaml: design.trees: got 0 (int); expected a value greater than or equal to 1"),
    ("general", "design.trees", 2.5, "bad.yaml: design.trees: got 2.5 (float)"),
    ("general", "design.tortuosity", ["simple", "wiggly"], "bad.yaml: design.tortuosity[1]: got 'wiggly' (str); expected 'simple', 'moderate' or 'tortuous'"),
    ("general", "design.type", "forest", "bad.yaml: design.type: got 'forest' (str); expected one of 'trees', 'n_views', 'angles'"),
    ("general", "design.views", "RAO 30 CRA 30; XYZ", "bad.yaml: design.views:"),
    ("general", "metrics", ["dice3d", "hausdorff"], "bad.yaml: metrics[1]: got 'hausdorff' (str)"),
    ("general", "reconstruction.engine", "magic", "bad.yaml: reconstruction.engine: got 'magic' (str); expected 'octree', 'kdtree', 'lookup' or 'auto'"),
    ("general", "reconstruction.resolution", 1, "bad.yaml: reconstruction.resolution: got 1 (int); expected a value greater than or equal to 2"),
    ("general", "reconstruction.threshold_px", -1.0, "bad.yaml: reconstruction.threshold_px: got -1.0 (float); expected a value greater than 0"),
    ("general", "generator.sod_mm", 1300, "bad.yaml: generator.sod_mm: got 1300.0; expected a value smaller than sid_mm (1200.0)"),
    ("general", "generator.corruptions", ["fp=2"], "bad.yaml: generator.corruptions[0]: corruption fp: p must lie in [0, 1], got 2.0"),
    ("false_positives", "design.sweep.values.grid.stop", 1.5, "bad.yaml: design.sweep.values.grid.stop: corruption fp: p must lie in [0, 1], got 1.5"),
    ("false_positives", "design.sweep.values.grid.stop", -1.0, "bad.yaml: design.sweep.values.grid.stop: got -1.0; expected a value greater than start (0.0)"),
    ("scaling", "design.sweep.values", {"uniform": {"low": 0.0, "high": 2.0, "count": 5}}, "bad.yaml: design.sweep.values.uniform.low: corruption scale: the factor must be > 0, got 0.0"),
    ("translation", "design.sweep.values", {"grid": {"start": 0, "stop": 1, "count": 3}}, "bad.yaml: design.sweep.values.grid: translate takes 'uniform'"),
    ("translation", "design.sweep.values", {"uniform": {"low": 0, "high": 1, "count": 3}, "list": [[1, 2]]}, "bad.yaml: design.sweep.values: got uniform, list; expected exactly one of grid, uniform, list"),
    ("translation", "design.sweep.values", {"list": [[1, 2], 3]}, "bad.yaml: design.sweep.values.list[1]: got 3.0; expected a [tx, ty] pair"),
    ("translation", "design.sweep.views", [5], "bad.yaml: design.sweep.views: got view index 5; expected an index below 3"),
    ("translation", "design.sweep.views", [], "bad.yaml: design.sweep.views: got [] (list)"),
    ("general", "generator.corruptions", ["fn=0.1@7"], "bad.yaml: generator.corruptions[0]: got view index 7; expected an index below 3"),
    ("n_views", "reconstruction.calibrate_scale", True, "bad.yaml: reconstruction.calibrate_scale: needs three views or more in every case; this design's smallest case has 1"),
    ("n_views", "design.n_views", {"min": 1, "max": 2000}, "bad.yaml: design.n_views.max: got 2000; expected at most directions (1000)"),
    ("n_views", "design.n_views", {"min": 5, "max": 2}, "bad.yaml: design.n_views.max: got 2; expected a value >= min (5)"),
    ("translation", "report.ttest", "chamfer_mm", "bad.yaml: report.ttest: t-tests compare tortuosity groups"),
    ("general", "quick.fraction", 0, "bad.yaml: quick.fraction: got 0 (int); expected a value greater than 0"),
    ("general", "name", "My Experiment!", "bad.yaml: name: got 'My Experiment!' (str)"),
])
def test_bad_configs_are_rejected_naming_the_field(tmp_path, base, field, value, expected):
    data = _edit(config_to_dict(load_config(base)), field, value)
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, data))
    assert expected in str(info.value), str(info.value)


_SWEEP_VIEWS = "'all', or a list of view indices (whole numbers from 0; at least one), e.g. [0] or [0, 2]"
_VIEWS = ("'perpendicular', 'clinical', clinical angle strings separated by ';' (e.g. 'RAO 30 CRA 30; LAO 60 CRA 30'), "
          "or a list of such strings")


@pytest.mark.parametrize("base, field, value, expected", [
    # fields typed as unions: one line in plain words, not one per form named "tuple[constrained-int, ...]"
    ("translation", "design.sweep.views", "some", f"design.sweep.views: got 'some' (str); expected {_SWEEP_VIEWS}"),
    ("translation", "design.sweep.views", [-1], f"design.sweep.views: got [-1] (list); expected {_SWEEP_VIEWS}"),
    ("translation", "design.sweep.views", [], f"design.sweep.views: got [] (list); expected {_SWEEP_VIEWS}"),
    ("translation", "design.sweep.views", [0.5], f"design.sweep.views: got [0.5] (list); expected {_SWEEP_VIEWS}"),
    ("general", "design.views", 3, f"design.views: got 3 (int); expected {_VIEWS}"),
    ("general", "design.views", [1, 2], f"design.views: got [1, 2] (list); expected {_VIEWS}"),
    ("translation", "design.sweep.values", {"list": ["a"]},
     "design.sweep.values.list[0]: got 'a' (str); expected a number, or a [tx, ty] pair of numbers (translate)"),
    ("translation", "design.sweep.values", {"list": [[1, 2, 3]]},
     "design.sweep.values.list[0]: got [1, 2, 3] (list); expected a number, or a [tx, ty] pair of numbers (translate)"),
    # lists: YAML's word, and a list whose items failed is not also 'too short'
    ("translation", "design.sweep.values", {"list": 5}, "design.sweep.values.list: got 5 (int); expected a list"),
    ("translation", "design.sweep.values", {"list": []},
     "design.sweep.values.list: got [] (list); expected a list of at least 1 item(s)"),
    ("general", "design.tortuosity", ["wiggly"],
     "design.tortuosity[0]: got 'wiggly' (str); expected 'simple', 'moderate' or 'tortuous'"),
    ("general", "metrics", "dice3d", "metrics: got 'dice3d' (str); expected a list"),
])
def test_union_and_list_fields_say_the_accepted_forms_in_one_line(tmp_path, base, field, value, expected):
    data = _edit(config_to_dict(load_config(base)), field, value)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: {expected}"


def test_more_selections_than_distinct_subsets_get_a_warning(tmp_path):
    from angiohull.errors import InputWarning

    data = config_to_dict(load_config("n_views"))
    data["design"].update(directions=4, n_views={"min": 1, "max": 3}, selections=5)
    with pytest.warns(InputWarning, match=r"design: 4 directions hold only 4 distinct selections of 1 views, fewer than "
                                          r"the 5 selections asked for \(and so for N = \[3\]\): some cases repeat"):
        load_config(_write(tmp_path, data))


def test_missing_keys_and_every_problem_are_reported(tmp_path):
    data = _general()
    del data["seed"]
    data["design"]["trees"] = -1
    with pytest.raises(ConfigError) as info:
        load_config(_write(tmp_path, data))
    message = str(info.value)
    assert "bad.yaml: seed: required key is missing" in message
    assert "bad.yaml: design.trees: got -1 (int)" in message


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read the experiment config"):
        load_config(tmp_path / "absent.yaml")
    (tmp_path / "broken.yaml").write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match=r"broken.yaml: invalid YAML at line \d+"):
        load_config(tmp_path / "broken.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="list.yaml: expected a mapping"):
        load_config(tmp_path / "list.yaml")
    with pytest.raises(ConfigError, match="no shipped experiment named 'genral'; expected a YAML file or one of: angles"):
        load_config("genral")


def test_round_trip_through_the_resolved_dict():
    for name in shipped_config_names():
        config = load_config(name, quick=True)
        assert config_from_dict(config_to_dict(config)) == config


def test_cli_rejects_a_bad_config_before_any_work(tmp_path, capsys):
    path = _write(tmp_path, _edit(_general(), "design.trees", 0))
    out = tmp_path / "run"
    assert main(["experiment", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml: design.trees: got 0 (int)" in err
    assert not out.exists()


def test_calibrate_scale_implies_calibrate():
    # Scales are estimated together with the shifts, so the one option turns on the other, in the
    # experiment configuration and in the study options alike.
    from angiohull.experiments.config import ReconstructionSettings
    from angiohull.workflow import ReconstructOptions

    assert ReconstructionSettings(calibrate_scale=True).calibrate is True
    assert ReconstructionSettings().calibrate is False
    assert ReconstructOptions(calibrate_scale=True).calibrate is True
    assert ReconstructOptions().calibrate is False
