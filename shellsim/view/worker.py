""" "Simulate in place": the scene job (:func:`shellsim.jobs.scene.scene`) in a worker process.

The worker runs exactly what ``shellsim scene SCENE.toml --out OUT`` runs (the same files, the same resume
of a motion of the same scene, the same lock on the output), so that nothing differs between a motion made
from the page and one made at the command line. The viewer reads the frames as they arrive from the run's
log (``OUT/motion.npz.partial``, :mod:`shellsim.motion.log`). A :class:`~neural.errors.ShellsimError` of
the job comes back as its one line (:attr:`Simulation.error`). Stopping the worker (Ctrl-C in the terminal,
which reaches the worker too, or :meth:`Simulation.stop`) interrupts the job as Ctrl-C interrupts the
command: the frames recorded so far are published and a later run continues them.
"""

from __future__ import annotations

import logging
import multiprocessing
import queue
import signal

log = logging.getLogger(__name__)

#: Seconds :meth:`Simulation.stop` waits for the worker to save what it made before it is killed.
STOP_SECONDS = 20.0


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt()


def _run(settings, results, verbose: bool) -> None:
    """In the worker process: the scene job of ``settings``; puts ``("done", frames)``, ``("error",
    line)`` or ``("interrupted", "")`` on ``results``."""
    from neural.device import configure_process
    from neural.errors import ShellsimError
    from shellsim.jobs.scene import scene

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _interrupt)
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    configure_process(verbose=verbose)
    try:
        result = scene(settings, progress=False)
    except ShellsimError as err:
        results.put(("error", str(err)))
    except KeyboardInterrupt:
        results.put(("interrupted", ""))
    except Exception as err:  # a bug: its one line on the page, its traceback in the worker's log
        log.exception("the simulation failed")
        results.put(("error", f"the simulation failed: {type(err).__name__}: {err}"))
    else:
        results.put(("done", result.frames))


class Simulation:
    """One run of the scene job in a spawned process (module docstring).

    settings : :class:`shellsim.jobs.scene.SceneSettings`
    """

    def __init__(self, settings, verbose: bool = False):
        context = multiprocessing.get_context("spawn")
        self.settings = settings
        self._results = context.Queue()
        self._process = context.Process(
            target=_run, args=(settings, self._results, verbose), name="shellsim-simulate", daemon=True
        )
        self.outcome: tuple[str, object] | None = None
        self._process.start()
        log.info("simulating %s into %s (process %d)", settings.scene, settings.out_dir, self._process.pid)

    @property
    def running(self) -> bool:
        """Whether the job still runs (its outcome not yet received)."""
        return self.poll() is None

    @property
    def error(self) -> str | None:
        """The job's one-line error, None while it runs or when it did not fail."""
        outcome = self.poll()
        return outcome[1] if outcome is not None and outcome[0] == "error" else None

    def poll(self):
        """The outcome ``(kind, value)`` once the job ended (``kind``: "done", "error", "interrupted"), else
        None."""
        if self.outcome is None:
            try:
                self.outcome = self._results.get_nowait()
            except queue.Empty:
                if not self._process.is_alive():
                    try:
                        self.outcome = self._results.get(timeout=1.0)
                    except queue.Empty:
                        code = self._process.exitcode
                        self.outcome = ("error", f"the simulation's process ended with status {code}")
        return self.outcome

    def stop(self, timeout: float = STOP_SECONDS) -> None:
        """Interrupt the job (it saves what it made, as Ctrl-C does) and wait for it; kill it after
        ``timeout`` seconds."""
        process = self._process
        if process.is_alive():
            process.terminate()  # SIGTERM: a KeyboardInterrupt in the job
            process.join(timeout)
            if process.is_alive():
                log.warning(
                    "the simulation did not stop in %g s; killed (its last chunk may be lost)", timeout
                )
                process.kill()
                process.join()
        self.poll()

    def join(self, timeout: float | None = None) -> None:
        self._process.join(timeout)
