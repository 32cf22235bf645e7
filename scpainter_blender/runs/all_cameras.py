"""Every camera path's backend run, one after another (*Render Conditions* / *Generate* for all camera paths): each
camera's run is one ``camera_run`` run (its job, its output folder, its results behind it); a camera whose render is
up to date has its results loaded without the backend (``render_plan``)."""

from __future__ import annotations

from ..core.errors import InputError
from ..scene import props
from . import render_plan
from .camera_run import ACTIVE, Follower, finish, progress_fraction, start, with_warnings
from .client import BackendError, Invocation


#: Report levels, mildest first: a report of several cameras has its worst camera's level.
LEVELS = ("INFO", "WARNING", "ERROR")


def error_text(e: InputError | BackendError) -> str:
    """One line for a camera whose run failed on bad input or in the backend (its hint added)."""
    hint = getattr(e, "hint", None)
    return str(e) + (f" ({hint})" if hint and hint not in str(e) else "")


class AllCameras:
    """``command`` run for each of ``cameras`` (``kinds.camera_paths``) one after another, each as ``start`` runs
    one camera (its job, its output folder, its results behind it), the scene camera left as it is; a camera whose
    render is up to date (``render_plan.check``) has its results loaded without a backend. Followed like a
    ``Follower`` (``tick(context)``, ``stop``, ``report``): from the UI timer, or in a loop by the blocking
    operator. A camera that cannot run (bad input such as a clashing folder name, a backend failure, a timeout) is
    reported and the next one runs; ``stop`` (Esc) stops the one running and starts no more. ``ACTIVE`` carries
    ``position`` (i, n), so the progress reads "render, camera 2/3: render 4/16"."""

    def __init__(self, context, command: str, run: Invocation, cameras: list, timeout: float = 0.0,
                 model: str | None = None):
        """SceneError when ``cameras`` is empty; otherwise the first camera's run is started."""
        if not cameras:
            raise props.SceneError("scene.objects", "the scene has no camera paths",
                                   hint="add one with New Camera Path in the SCPainter panel")
        self.command, self.run, self.timeout, self.model = command, run, timeout, model
        self.names = [c.name for c in cameras]  # names, not objects: a camera may be deleted during the runs
        self.outcomes: list[tuple[str, str, str, str]] = []   # (camera, status, level, message), in order
        self.follower: Follower | None = None
        self._next(context)

    @property
    def fraction(self) -> float:
        return progress_fraction() if ACTIVE else len(self.outcomes) / len(self.names)

    @property
    def status_text(self) -> str:
        return self.follower.status_text if self.follower is not None and ACTIVE else "SCPainter"

    def _next(self, context) -> bool:
        """Start the next camera's run; one that cannot start is recorded and skipped. False when none is left."""
        while len(self.outcomes) < len(self.names):
            i, name = len(self.outcomes), self.names[len(self.outcomes)]
            try:
                cam = context.scene.objects.get(name)
                if cam is None:
                    raise props.SceneError(f"objects[{name!r}]", "is no longer in the scene (deleted or renamed "
                                                                 "while the camera paths before it ran)")
                found = render_plan.check(context, self.run, cam)
                if found is not None and found.done is not None:  # up to date: no backend for this camera
                    level, message = with_warnings(finish(context, self.command, found.out, found.done, name),
                                                   found.warnings)
                    self.outcomes.append((name, "finished", level, message))
                    continue
                job, out = start(context, self.run, camera=cam,
                                 exported=None if found is None else (found.job_path, found.out))
            except (InputError, BackendError) as e:
                self.outcomes.append((name, "failed", "ERROR", error_text(e)))
                continue
            self.follower = Follower(self.command, job, out, self.timeout, self.model, camera=name,
                                     position=(i + 1, len(self.names)))
            return True
        self.follower = None
        return False

    def tick(self, context=None) -> str:
        """'running' while a camera's run goes on or the next one started; 'finished' when every camera had its
        run (each one's outcome in ``outcomes``)."""
        if self.follower is None:
            return "finished"
        status = self.follower.tick()
        if status == "running":
            return status
        self._record(context, status)
        return "running" if self._next(context) else "finished"

    def _record(self, context, status: str) -> None:
        """The ended run's outcome (its results loaded when it finished)."""
        try:
            level, message = self.follower.report(context, status)
        except InputError as e:  # its results could not be loaded (a bug propagates)
            level, message = "ERROR", error_text(e)
        self.outcomes.append((self.follower.camera, status, level, message))
        self.follower = None

    def stop(self) -> None:
        """Esc: the running camera's backend is stopped (its finished frames kept); no other camera starts."""
        if self.follower is not None:
            self.follower.stop()

    def report(self, context, status: str) -> tuple[str, str]:
        """(level, message) for the end: how many cameras finished, and each camera's own report; the worst
        camera's level (a cancelled run: at least WARNING)."""
        if status != "finished" and self.follower is not None:
            self._record(context, "cancelled" if status == "cancelled" else status)
        not_run = self.names[len(self.outcomes):]
        ok = sum(st == "finished" and level != "ERROR" for _, st, level, _ in self.outcomes)
        levels = [level for _, _, level, _ in self.outcomes] + ["WARNING"] * bool(not_run)
        head = f"{self.command} of {len(self.names)} camera path{'s' * (len(self.names) > 1)}: {ok} finished"
        if not_run:
            head += f", not run: {', '.join(map(repr, not_run))}"
        parts = [f"{name!r}: {message}" for name, _, _, message in self.outcomes]
        return max(levels, key=LEVELS.index, default="INFO"), "; ".join([head, *parts])
