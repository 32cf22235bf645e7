"""``import backend`` (what ``python -m backend`` runs first) makes OpenMP wait passively: torch's libgomp and numba's
``omp`` threading layer both start with a spin count of 0, unless the user named a policy."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# the backend package first, then torch, then numba's thread pool (get_num_threads starts it: numba's OpenMP
# runtime loads then, as on a first parallel kernel)
CHILD = """
import os, backend, torch, numba
numba.get_num_threads()
print("policy", os.environ.get("OMP_WAIT_POLICY"), "layer", numba.threading_layer())
"""


def run_child(policy):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if policy is not None:
        env["OMP_WAIT_POLICY"] = policy
    env["OMP_DISPLAY_ENV"] = "VERBOSE"  # libgomp prints its settings on standard error when it loads
    p = subprocess.run([sys.executable, "-c", CHILD], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    words = p.stdout.split()
    spin = [line.split("=")[1].strip().strip("'") for line in p.stderr.splitlines() if "GOMP_SPINCOUNT" in line]
    shown = [line.split("=")[1].strip().strip("'") for line in p.stderr.splitlines()
             if line.strip().startswith("OMP_WAIT_POLICY")]
    return words[words.index("policy") + 1], words[words.index("layer") + 1], spin, shown


def test_passive_by_default_in_every_openmp_runtime():
    policy, layer, spin, shown = run_child(None)
    assert policy == "PASSIVE"
    runtimes = 2 if layer == "omp" else 1  # torch's libgomp, and numba's own copy when its layer is omp
    assert spin == ["0"] * runtimes and shown == ["PASSIVE"] * runtimes


def test_a_users_policy_is_kept():
    policy, layer, spin, shown = run_child("ACTIVE")
    assert policy == "ACTIVE" and shown == ["ACTIVE"] * (2 if layer == "omp" else 1)
