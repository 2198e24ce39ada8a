"""Errors a user can cause and fix; the CLI prints them on one line and exits with code 2."""


class UsageError(ValueError):
    """Bad input: an unknown name, a value out of range, a file that holds no run.

    The message says what was wrong and, where there is a choice, what the valid choices are.
    """
