"""The one exception class the command line reports to the user instead of a traceback.

Every error a user can fix by changing their input (a parameter key or value, a placement
file, a scenario name, an option, a program file) derives from :class:`UserError`; its message
is one line naming what is wrong and where (file, line, key). ``kilonet`` prints it after
``kilonet: error:`` and exits with status 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

__all__ = ["UserError"]


class UserError(Exception):
    """Input the user can fix; ``str()`` is one line saying what is wrong and where."""
