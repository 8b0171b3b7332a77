"""The test kit's one error: misuse of a scripted world or swarm."""

__all__ = ["ScriptError"]


class ScriptError(ValueError):
    """A scripted world or swarm used in a way it cannot honour (time going backwards, an
    unknown robot, a distance nobody could be heard from); the message says what and how to
    fix it."""
