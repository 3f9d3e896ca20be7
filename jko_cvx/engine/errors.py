"""The errors of the study engine."""

__all__ = ["RunDirError"]


class RunDirError(ValueError):
    """A run directory that cannot be used as asked; the message names the directory or file."""
