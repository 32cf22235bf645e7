"""The test-only loaders (tests/loaders.py) import in their subprocess: torchvision's dataset code and vcd."""

import os

import loaders


def test_the_loaders_import_in_their_subprocess():
    if not os.environ.get("CI"):
        loaders.require("torchvision", "vcd")  # CI installs them (tools/setup.sh): there a missing one fails
    out = loaders.run("import torchvision, vcd.core, vcd.scl\n"
                      "from torchvision.datasets import CocoDetection, wrap_dataset_for_transforms_v2\n"
                      "print(json.dumps({'torchvision': torchvision.__version__, 'in_test': 'torchvision' in sys.modules}))")
    assert out["torchvision"].startswith("0.28.0") and out["in_test"]
    import sys
    assert "torchvision" not in sys.modules  # the test process never imports them
