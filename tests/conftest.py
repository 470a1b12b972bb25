"""Shared fixtures. Data under ../shared (beside the checkout) is optional: tests that need it skip.

The suite runs in parallel with pytest-xdist (``-n auto --dist loadscope`` in pyproject's addopts:
one worker per CPU this process may use). ``python -m pytest -n 0`` or ``-p no:xdist`` runs it in
one process (for ``--pdb``, ``-s``, profiling); without pytest-xdist installed it runs in one process
too. Tests that share an expensive module- or session-scoped fixture run on one worker, so that it
is built once (``pytest_xdist_make_scheduler``).
"""

import os
import re
from pathlib import Path

# Under pytest-xdist each worker is one of N processes on N CPUs: a BLAS that starts a thread per CPU
# in every worker would oversubscribe them (and its work is many small products, which run faster
# single-threaded: see angiohull.cli.main, which does the same). Set before NumPy is first imported.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _variable in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.setdefault(_variable, "1")

import pytest

#: Session-scoped fixtures that take long to build: under pytest-xdist, every module that uses one
#: runs on one worker (``pytest_xdist_make_scheduler``).
SHARED_SESSION_FIXTURES = ("quick_runs",)


# -- parallel runs (pytest-xdist) -----------------------------------------------------------------
def pytest_addoption(parser, pluginmanager):
    """With pytest-xdist off (``-p no:xdist``) or not installed, the ``-n``/``--dist`` of pyproject's
    addopts are accepted and ignored: the suite runs in this process."""
    if not pluginmanager.has_plugin("xdist"):
        group = parser.getgroup("xdist-off", "pytest-xdist is off or not installed")
        # _addoption: a one-letter lowercase option, as pytest-xdist itself declares -n
        group._addoption("-n", "--numprocesses", dest="numprocesses", default=None,
                         help="ignored: the tests run in this process")
        group.addoption("--dist", dest="dist", default="no", help="ignored: the tests run in this process")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per CPU this process may run on (pytest-xdist would count physical
    cores, which is 1 on a 2-vCPU machine with hyper-threading). ``PYTEST_XDIST_AUTO_NUM_WORKERS``
    still overrides it."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _module_scope(path: Path):
    """How the tests of one module are sent to the workers: the name of a shared session fixture
    the module uses (all its tests go with every other user of that fixture), the module itself when
    it defines a module-scoped fixture, or None (its tests are spread one by one). Read from the
    module's text: a false match only keeps tests together."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError:
        return None
    for name in SHARED_SESSION_FIXTURES:
        if re.search(rf"\b{name}\b", text):
            return name
    if re.search(r"scope\s*=\s*[\"']module[\"']", text):
        return "module"
    return None


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` (pyproject's addopts) with our scopes: the users of an expensive session
    fixture (``quick_runs``) on one worker, which builds it once; a module with a module-scoped
    fixture on one worker; every other test on its own, so that the long ones spread. (pytest-xdist's
    ``loadgroup`` would do this from ``xdist_group`` marks, but it stops grouping on pytest >= 9.2:
    pytest-xdist issue #1386.) Scopes with the most tests start first."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    root, scopes = config.rootpath, {}

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            if module not in scopes:
                scopes[module] = _module_scope(root / module)
            scope = scopes[module]
            return nodeid if scope is None else module if scope == "module" else scope

    return SharedFixtureScheduling(config, log)


def shared_root() -> Path:
    """``$ANGIOHULL_SHARED`` or the ``shared`` folder beside the repository checkout."""
    env = os.environ.get("ANGIOHULL_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(params=["compiled", "numpy"])
def kernel_backend(request):
    """Runs a test with the compiled kernels (numba; skipped where it is not installed) and with
    the NumPy reference code (angiohull.compiled)."""
    from angiohull import compiled

    if request.param == "compiled":
        pytest.importorskip("numba", reason="numba is not installed (pip install '.[fast]'): the compiled kernels "
                                            "are not tested")
    previous = compiled.set_enabled(request.param == "compiled")
    if request.param == "compiled" and compiled.kernels() is None:
        compiled.set_enabled(previous)
        pytest.skip(f"the compiled kernels do not load: {compiled.status()}")
    yield request.param
    compiled.set_enabled(previous)


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
    """Every shipped experiment run with --quick through the command line, in this process (about 40 s
    on one core; its users share one worker under pytest-xdist)."""
    from angiohull.cli import main

    root = tmp_path_factory.mktemp("quick-runs")
    assert main(["experiment", "all", "--quick", "-o", str(root), "--workers", "1", "--quiet"]) == 0
    return root
