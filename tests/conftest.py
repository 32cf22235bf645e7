"""Test session: the real bpy module, the add-on built and installed as Blender installs extensions.

``BLENDER_USER_RESOURCES`` points at a private folder before bpy is imported, so no test touches a real Blender
configuration. The ground-truth street is generated once and cached (``.cache/`` or ``$SCPAINTER_CACHE_DIR``).

Without bpy (a backend-only environment: requirements-backend.txt, ``make test-backend-only``) the same tests run
and each one that needs Blender is skipped, saying so (``NO_BPY``): importing ``bpy`` (or ``mathutils``, ``bmesh``)
anywhere in this process raises pytest's skip, so a test module that imports it at its top (tests/scene, directly
or through ``scpainter_blender.scene``) is skipped as a whole, a test or fixture that imports it inside (``addon``,
``extension_zip``, ``empty_scene``) is skipped where it asks, and everything else runs. Whether bpy is there is
decided by whether it is installed (``find_spec``), never by a failed import: in .venv a broken bpy fails loudly.
The street is read from the cache; only generating it needs bpy.
"""

import importlib.abc
import importlib.util
import os
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

# Before anything loads torch (libgomp reads both once, when it loads), for this process and every process the tests
# start (backend subprocesses, Ray workers, torchrun): ``import backend`` sets OMP_WAIT_POLICY=PASSIVE as
# ``python -m backend`` does, and torch gets one intra-op thread. The tests' models are tiny: a second thread gains
# little on an idle 2-core machine, but beside one busy process every parallel region waits for a descheduled
# thread: a training step of the tiny model took 14.8 s with 2 threads, 0.58 s with 1 (load 9 on 2 cores), which is
# how test_tiny_model_overfits_one_batch once took 464 s. numba (the renderer) keeps its own thread count: its omp
# layer sets it per region, so the renderer's parallel paths are still tested. A value the caller set is kept.
os.environ.setdefault("OMP_NUM_THREADS", "1")
import backend  # noqa: E402,F401  (OMP_WAIT_POLICY, NUMBA_CACHE_DIR: backend/__init__.py says why)

from tools import blender_env  # noqa: E402

NO_BPY = "needs Blender (bpy is not installed: a backend-only environment, requirements-backend.txt)"
BLENDER_MODULES = ("bpy", "mathutils", "bmesh", "bpy_extras")  # what only Blender's Python (the bpy wheel) has


class _NoBlender(importlib.abc.MetaPathFinder):
    """Where bpy is not installed: an import of a Blender module skips the test (module, fixture or test body) that
    made it, as ``pytest.importorskip`` would, instead of failing it with ModuleNotFoundError."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLENDER_MODULES:
            frame = sys._getframe(1)  # the import statement that asked, past importlib's own frames
            while frame is not None and frame.f_code.co_filename.startswith("<frozen importlib"):
                frame = frame.f_back
            where = f" ({os.path.relpath(frame.f_code.co_filename, ROOT)}:{frame.f_lineno})" if frame else ""
            raise pytest.skip.Exception(f"{NO_BPY}: imports {name}{where}", allow_module_level=True)
        return None


if importlib.util.find_spec("bpy") is not None:
    _USER = blender_env.use_private_user_resources(tempfile.mkdtemp(prefix="scpainter-test-user-"))
    import bpy  # noqa: E402  (after BLENDER_USER_RESOURCES)
else:
    _USER = None
    sys.meta_path.insert(0, _NoBlender())


def pytest_addoption(parser):
    parser.addoption("--run-slow", action="store_true", help="run tests marked slow")


class _RootIsTheAddOn:
    """The repository root's ``__init__.py`` is the add-on's (Blender imports it as ``bl_ext.<repo>.scpainter``):
    pytest (8) would collect the root as a test package and import it in every test's setup, bpy and the whole
    add-on under the clone's folder name. Collected as a plain folder, it is never imported here: the tests reach the
    add-on as Blender does (``addon``), and without bpy the backend's tests do not depend on it.

    A plugin, not a hook of this file: a conftest's hooks apply below its folder, and the root lies above it."""

    @pytest.hookimpl(tryfirst=True)
    def pytest_collect_directory(self, path, parent):
        if os.path.realpath(path) == os.path.realpath(ROOT):
            return pytest.Dir.from_parent(parent, path=path)
        return None


def pytest_configure(config):
    config.pluginmanager.register(_RootIsTheAddOn(), "scpainter-root-is-the-add-on")


def pytest_collection_modifyitems(config, items):
    run_slow = config.getoption("--run-slow")
    has_cuda = False
    if any("gpu" in item.keywords for item in items):  # import torch only when a GPU test asks for it
        try:
            import torch

            has_cuda = torch.cuda.is_available()
        except ImportError:
            pass
    for item in items:
        if "slow" in item.keywords and not run_slow:
            item.add_marker(pytest.mark.skip(reason="slow: run with --run-slow"))
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="needs CUDA"))


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory):
    """The extension built and validated by Blender's own tool (skipped without bpy)."""
    return blender_env.build_extension(str(tmp_path_factory.mktemp("dist")))


@pytest.fixture(scope="session")
def addon(extension_zip):
    """The built zip installed into a local extension repository and enabled; yields its package name."""
    pkg = blender_env.install_zip(extension_zip, os.path.join(_USER, "extensions", "scpainter_local"))
    yield pkg


@pytest.fixture
def empty_scene(addon):
    """A fresh empty scene with the add-on still enabled."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


@pytest.fixture(scope="session")
def street():
    """The default ground-truth street (generated once, then cached between runs). Generating it renders with
    Blender: without bpy a street not in the cache skips the tests that need it."""
    from scpainter_blender.street.dataset import cached_street, ensure_street

    if _USER is None and cached_street() is None:
        pytest.skip(f"{NO_BPY}: the ground-truth street is not in the cache, and generating it renders with Blender "
                    "(run `make test` or `make demo` once to cache it)")
    return ensure_street()


# -- tiny SVD snapshots and SCPainter checkpoints, built from configs (random weights, nothing downloaded) -------

@pytest.fixture(scope="session")
def tiny_svd(tmp_path_factory):
    from backend.model import configs

    return configs.save_stock_svd(str(tmp_path_factory.mktemp("svd") / "svd-tiny"), "tiny", seed=0)


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_svd, tmp_path_factory):
    from backend.model import checkpoint_init

    return checkpoint_init.init_checkpoint(tiny_svd, str(tmp_path_factory.mktemp("ckpt") / "scpainter-tiny"))


@pytest.fixture(scope="session")
def street_clip_path(street, tmp_path_factory):
    """The ground-truth street exported as a training clip (clip.json path)."""
    from backend.train import street_clip

    return street_clip.export_clip(street, str(tmp_path_factory.mktemp("clips") / "street"))


# -- Ray ---------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def ray_cluster():
    """A new local Ray cluster of 2 CPUs (2 workers at a time; never a `ray start` left running), shared by every
    test that asks for it; yields its address (``HOST:PORT`` of its head), which a subprocess such as
    ``python -m backend batch --ray ADDRESS`` connects to. Skipped without ``ray``."""
    import signal

    ray = pytest.importorskip("ray")
    # The cluster's processes inherit this one's SIGINT disposition. A shell starts a background job (`bash .ci/run
    # &`) with SIGINT ignored; a worker started so installs no KeyboardInterrupt handler, and Ray's cancel of a
    # running task (raised in the worker through SIGINT: _thread.interrupt_main) does nothing there. Started with
    # Python's handler here, as from a terminal, the workers get the default disposition however the tests started.
    found = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        ray.init(address="local", num_cpus=2, log_to_driver=False, include_dashboard=False, configure_logging=False,
                 runtime_env={"env_vars": {"PYTHONPATH": ROOT}})
    finally:
        signal.signal(signal.SIGINT, found)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()
