"""Configuration errors that name the file, the field and the problem in one line."""

from __future__ import annotations


class ConfigError(ValueError):
    """Bad user input (scenario, parameters, calibration data).

    ``str(err)`` is one line: ``FILE: FIELD: problem`` (parts that are unknown are left out).
    The command line prints it and exits with code 2; nodes log it and exit non-zero.
    """

    def __init__(self, problem: str, field: str | None = None, file: str | None = None):
        self.problem = problem
        self.field = field
        self.file = file
        super().__init__(self._line())

    def _line(self) -> str:
        parts = [p for p in (self.file, self.field) if p]
        return ': '.join(parts + [self.problem])

    def with_file(self, file: str) -> 'ConfigError':
        """The same error, naming ``file``."""
        return ConfigError(self.problem, self.field, file)

    def under(self, prefix: str) -> 'ConfigError':
        """The same error with ``prefix`` prepended to the field path
        (``robots[1]`` + ``.slot_m``).
        """
        field = f'{prefix}.{self.field}' if self.field else prefix
        if self.field and self.field.startswith('['):
            field = f'{prefix}{self.field}'
        return ConfigError(self.problem, field, self.file)
