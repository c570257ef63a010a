"""The two kinds of failure a user sees, each with its exit status.

A user's mistake (a bad scene key or value, a bad run option, a missing or foreign
result file, an output folder that cannot be written, an interrupted file resumed
with another scene) is a `UserError`:
one line, exit status 2. A solver that cannot reach the answer (divergence,
iteration limit, friction cycling at an opening contact) is a `SolverError`:
one line, exit status 3, with every finished load step kept on disk.
"""


class DynfabError(Exception):
    """Base of the errors the command line turns into one message and an exit status."""

    exit_status = 1


class UserError(DynfabError, ValueError):
    """A user's mistake in what they gave dynfab (scene, options, files, folders): one line
    naming the key, value or path and what is allowed. Exit status 2."""

    exit_status = 2


class SolverError(DynfabError, RuntimeError):
    """The solver stopped without an answer for a load step. Exit status 3."""

    exit_status = 3
