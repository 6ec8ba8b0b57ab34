"""User-facing errors: each says what is wrong and how to fix it, on one line."""

from __future__ import annotations


class HarnessError(Exception):
    """An error caused by the user's input, reported as one line with a fix."""

    def __init__(self, problem: str, fix: str):
        super().__init__(f"{problem}; fix: {fix}")
        self.problem = problem
        self.fix = fix

    def __reduce__(self):
        # rebuilt from (problem, fix), so it crosses a process pool intact
        return self.__class__, (self.problem, self.fix)


class DemoError(HarnessError):
    """A demonstration file that cannot be used."""


class TimeLimitStop(Exception):
    """A command stopped at its --time-limit: finished runs are kept, unfinished ones
    checkpointed, and the same command resumes them. Not a HarnessError: the input was fine
    and nothing failed."""
