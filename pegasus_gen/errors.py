"""User-facing errors: the CLI prints their message and exits non-zero, without a traceback."""


class PegasusError(Exception):
    """Bad user input (a file, a config value, a flag): the message names the thing and the problem."""


class SplatFileError(PegasusError):
    """A splat PLY file that cannot be read: the message starts with the file's path."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
