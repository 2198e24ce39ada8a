"""Errors a user can cause and fix; the CLI prints them on one line and exits with a code of its own."""


class UsageError(ValueError):
    """Bad input: an unknown name, a value out of range, a file that holds no run (exit code 2).

    The message says what was wrong and, where there is a choice, what the valid choices are.
    """


class TrainingDiverged(RuntimeError):
    """A loss or a parameter became NaN or infinite (exit code 3).

    The message names the metric and the env step and says what to change; the run folder keeps its
    last finite checkpoint.
    """


class StorageFull(OSError):
    """The disk (or quota) filled while writing ``path`` (exit code 4): nothing half-written stays
    behind, and the message names the bytes the file needed and what is still complete."""

    def __init__(self, path: object, needed: int, kept: str | None = None):
        message = (
            f"no space left on the device for {path} ({needed:,} bytes needed); its temporary file is gone"
        )
        if kept:
            message += f"; {kept}"
        super().__init__(message)
        self.path, self.needed = path, needed

    def __str__(self) -> str:
        return self.args[0]


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during a training (exit code 130); ``run_dir`` is what ``agentax train --resume`` continues."""

    def __init__(self, run_dir: str | None = None):
        super().__init__(run_dir)
        self.run_dir = run_dir


class NodeLost(RuntimeError):
    """A Ray node of a ``--runner ray`` run was lost and the run cannot go on without it (exit code 5).

    The message says what was lost; ``run_dir`` (set by the runner) is what ``agentax train --resume``
    continues from its last checkpoint. When the node lost is the learner's own, Ray ends the process
    itself (exit code 1) and :func:`agentax.train.ray.hint_if_ray_ends_this_process` says the same.
    """

    def __init__(self, message: str, run_dir: str | None = None):
        super().__init__(message)
        self.run_dir = run_dir
