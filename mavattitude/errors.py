"""Errors the CLI turns into one line on stderr and a non-zero exit."""


class InputError(Exception):
    """A log (or other input) we cannot use. The message names the file and the problem."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class UsageError(Exception):
    """The command line asks for something that cannot be done (exit 2)."""
