"""Size and load time of viewer.html, and the README's screenshot of it (issue 24).

For each result folder given (the OUT_DIR of `angiohull reconstruct` or `angiohull demo`), rebuilds
viewer.html with `angiohull view` (timed), reports its size split into plotly.js and the scene,
and loads it ``--repeats`` times in headless Chromium (the tests' driver, ``tests/_browser.py``):
the time from navigation until plotly has drawn the scene, median and range. With ``--screenshot
PNG`` the first folder's page is also captured (``--size`` pixels), as docs/viewer.png is.

    python benchmarks/viewer.py angiohull-demo REFINED_OUT [--repeats 5] [--screenshot docs/viewer.png]

The demo's folder comes from `angiohull demo`; a K = 256 refined case from
`angiohull reconstruct angiohull-demo/study -o REFINED_OUT --preset refined --qca`.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _browser import Browser  # noqa: E402

from angiohull.cli import main  # noqa: E402
from angiohull.viewer import plotly_js  # noqa: E402


def scene_of(page: str) -> dict:
    match = re.search(r'id="angiohull-figure">(.*?)</script>', page, re.S)
    return json.loads(match.group(1))


def main_(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--screenshot", type=Path, default=None)
    parser.add_argument("--size", default="1200x800", help="screenshot size WIDTHxHEIGHT (default 1200x800)")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    js_mb = len(plotly_js().encode()) / 1e6
    with Browser(width=width, height=height, timeout_s=120.0) as browser:
        for k, folder in enumerate(args.results):
            start = time.perf_counter()
            assert main(["view", str(folder), "-q"]) == 0
            build_s = time.perf_counter() - start
            page = folder / "viewer.html"
            text = page.read_text(encoding="utf-8")
            meta = scene_of(text)["angiohull"]
            loads, shot = [], None
            for _ in range(args.repeats):
                shot = browser.load(page.resolve().as_uri(), ready="window.angiohullReady === true")
                assert not shot.errors, shot.errors
                loads.append(shot.seconds)
            size_mb = page.stat().st_size / 1e6
            mesh = meta.get("mesh", {})
            print(f"{folder}: {size_mb:.2f} MB (plotly.js {js_mb:.2f} MB, scene {size_mb - js_mb:.2f} MB); "
                  f"built by `angiohull view` in {build_s:.2f} s; {meta['vessel_points']:,} lumen points "
                  f"({meta.get('shown_vessel_points', 0):,} drawn), mesh {mesh.get('faces', 0):,} faces "
                  f"({mesh.get('shown_faces', 0):,} drawn), {meta.get('lesions', 0)} lesions; load in headless "
                  f"Chromium (SwiftShader) median {statistics.median(loads):.2f} s "
                  f"({min(loads):.2f}-{max(loads):.2f}, {len(loads)} loads)")
            if k == 0 and args.screenshot is not None and shot is not None:
                args.screenshot.write_bytes(shot.png)
                print(f"wrote {args.screenshot}")
                groups = scene_of(text)["angiohull"]["groups"]
                if groups.get("truth"):  # the same page with "truth & error" pressed and the surface hidden
                    error_png = args.screenshot.with_name(args.screenshot.stem + "-error.png")
                    with browser.page(page.resolve().as_uri(), ready="window.angiohullReady === true") as tab:
                        tab.evaluate(f"Plotly.restyle('angiohull-plot', {{visible: true}}, {groups['truth']})"
                                     f".then(() => Plotly.restyle('angiohull-plot', {{visible: 'legendonly'}}, [0]))"
                                     f".then(() => true)", wait=True)
                        error_png.write_bytes(tab.shot().png)
                    print(f"wrote {error_png}")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
