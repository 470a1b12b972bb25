"""The README's Python API example runs as written (on a small synthetic study and XA file)."""

import re
from pathlib import Path

import numpy as np

from _dicom_files import write_xa
from angiohull.synthetic import SynthOptions, make_case, write_case
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram, to_counts

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_example() -> str:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Python API"):]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match is not None, "no python block under '## Python API' in README.md"
    return match.group(1)


def test_the_readme_api_example_runs_as_written(tmp_path, monkeypatch):
    # what the example reads: a study folder "my_study" and an XA file "IM1.dcm" in the working folder
    # (a synthetic RCA study at half the demo's resolution: the same field of view, 256 x 256 pixels)
    case = make_case(SynthOptions(seed=2025, size=256, pixel_mm=0.7))
    write_case(tmp_path / "my_study", case)
    view = case.views[0]
    image = render_angiogram(case.tree.phantom, view.carm, 1, AngiogramParameters(collimator_px=6))
    carm = view.carm
    write_xa(tmp_path / "IM1.dcm", to_counts(image.image, bits=12), primary=carm.primary_deg,
             secondary=carm.secondary_deg, sid=carm.sid_mm, sod=carm.sod_mm, spacing=carm.pixel_spacing_mm)
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "readme_example"}
    exec(compile(readme_example(), str(README) + " (## Python API)", "exec"), namespace)
    assert namespace["tree"] is not None and len(namespace["result"].vessel_points_mm) > 0
    assert (tmp_path / "out" / "tree.swc").is_file()
    assert namespace["mask"].shape == (256, 256) and namespace["mask"].any()
    assert isinstance(namespace["qca"].lesion_rows(), list)
    assert np.isfinite(namespace["tree"].length_mm)
