"""The one base of every error a user is meant to read.

Each error the library raises for bad input or a failed run derives from `R2pacError` (and from
the builtin it refines, so `except ValueError` or `except OSError` keep working); its message is
one line that names the problem and the fix. The command lines catch `R2pacError` alone and
print that line (exit 2); anything else is a bug and keeps its traceback.
"""
from __future__ import annotations


class R2pacError(Exception):
    """Base of the library's user-facing errors (config, data, tasks, runs, files)."""


class ConfigError(R2pacError, ValueError):
    """A configuration value (or key) a run cannot use; raised by `config`, `ranges` and each
    algorithm's own checks, below the algorithms so that they and the planner share it."""
