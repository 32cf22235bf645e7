"""``render`` with its output tree or an input swapped for a link between the check and the use (issue 42): a
conditions/ swapped after render made it received frames (7 of 8 trials), an asset swapped after the check was read
(4 of 4). The swap is done in-process at the point between the two (a wrapped function), so no timing decides."""

import os

from backend.render import command as render_command
from scpainter_blender.core import outputs
from tests_support import run_backend_here, small_job


def run(*args):
    """(exit code, events) of ``python -m backend *args`` run in this process, with no traceback."""
    code, evs, err = run_backend_here(*args)
    assert "Traceback" not in err, err
    return code, evs


def test_conditions_swapped_for_a_link_after_it_was_made_receive_nothing(tmp_path, monkeypatch):
    job = small_job(tmp_path / "job")
    outside = tmp_path / "outside"
    outside.mkdir()
    made = outputs.output_folder

    def make_then_swap(parent, name, allow_outside=False):
        path = made(parent, name, allow_outside)         # made and checked ...
        os.rename(path, path + ".moved")                 # ... then swapped for a link leading out
        os.symlink(outside, path)
        return path

    monkeypatch.setattr(outputs, "output_folder", make_then_swap)
    code, events = run("render", job, "--device", "cpu")
    assert code == 2 and events[-1]["event"] == "error" and "replaced" in events[-1]["message"]
    assert os.listdir(outside) == []


def test_an_asset_swapped_for_a_link_after_the_check_is_not_rendered(tmp_path, monkeypatch):
    job = small_job(tmp_path / "job")
    secret = tmp_path / "secret"
    secret.mkdir()
    car = os.path.join(os.path.dirname(job), "car.ply")
    with open(car, "rb") as f:
        (secret / "car.ply").write_bytes(f.read())
    warn = render_command.warn_inputs

    def checked_then_swap(*args, **kwargs):              # render_job's last step between its check and its reads
        os.remove(car)                                   # every input was checked: now the asset becomes a link
        os.symlink(secret / "car.ply", car)
        return warn(*args, **kwargs)

    monkeypatch.setattr(render_command, "warn_inputs", checked_then_swap)
    code, events = run("render", job, "--device", "cpu")
    assert code == 2 and events[-1]["event"] == "error" and events[-1]["file"] == car
    assert "outside" in events[-1]["message"]
