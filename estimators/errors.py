"""Errors that mean "the user asked for something invalid", shared by every ``slung`` command.

The command-line front end turns a :class:`UserError` into one line on stderr and exit code 2; anything
else is a bug and keeps its traceback. Lives in ``estimators`` (the bottom layer) so that ``sim_bridge``
and ``offboard`` can both raise it without importing each other.
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input from the user: the message is one line that names the bad value and what is expected."""

    exit_code = 2
