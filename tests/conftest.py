"""Test session: the real bpy module, the add-on built and installed as Blender installs extensions.

``BLENDER_USER_RESOURCES`` points at a private folder before bpy is imported, so no test touches a real Blender
configuration. The ground-truth street is generated once and cached (``.cache/`` or ``$SCPAINTER_CACHE_DIR``).
"""

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

_USER = blender_env.use_private_user_resources(tempfile.mkdtemp(prefix="scpainter-test-user-"))

import bpy  # noqa: E402  (after BLENDER_USER_RESOURCES)


def pytest_addoption(parser):
    parser.addoption("--run-slow", action="store_true", help="run tests marked slow")


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
    """The extension built and validated by Blender's own tool."""
    return blender_env.build_extension(str(tmp_path_factory.mktemp("dist")))


@pytest.fixture(scope="session")
def addon(extension_zip):
    """The built zip installed into a local extension repository and enabled; yields its package name."""
    pkg = blender_env.install_zip(extension_zip, os.path.join(_USER, "extensions", "scpainter_local"))
    yield pkg


@pytest.fixture
def empty_scene(addon):
    """A fresh empty scene with the add-on still enabled."""
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


@pytest.fixture(scope="session")
def street():
    """The default ground-truth street (generated once, then cached between runs)."""
    from scpainter_blender.street.dataset import ensure_street

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
