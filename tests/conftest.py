"""Shared fixtures. Data under ../shared (beside the checkout) is optional: tests that need it skip."""

import os
from pathlib import Path

import pytest


def shared_root() -> Path:
    """``$ANGIOHULL_SHARED`` or the ``shared`` folder beside the repository checkout."""
    env = os.environ.get("ANGIOHULL_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(scope="session")
def peer_synthetic_dir() -> Path:
    """The authors' 48 peer-synthetic studies, or a skip when ../shared is absent."""
    folder = shared_root() / "benchmarks" / "peer-synthetic"
    if not (folder / "peer_results.csv").is_file():
        pytest.skip(f"peer-synthetic benchmark not found at {folder} (clone the project beside ../shared, "
                    f"or set ANGIOHULL_SHARED)")
    return folder


@pytest.fixture(scope="session")
def ge_phantom_dir() -> Path:
    """The three real GE XA runs of a static phantom (IM1, IM2, IM5), or a skip when ../shared is absent."""
    folder = shared_root() / "data" / "ge-xa-phantom"
    if not all((folder / f"IM{i}.dcm").is_file() for i in (1, 2, 5)):
        pytest.skip(f"real XA phantom files not found at {folder} (clone the project beside ../shared, "
                    f"or set ANGIOHULL_SHARED)")
    return folder


@pytest.fixture(scope="session")
def quick_runs(tmp_path_factory) -> Path:
    """Every shipped experiment run with --quick through the command line, in this process (~20 s)."""
    from angiohull.cli import main

    root = tmp_path_factory.mktemp("quick-runs")
    assert main(["experiment", "all", "--quick", "-o", str(root), "--workers", "1", "--quiet"]) == 0
    return root
