"""Configuration errors that name the file, the field and the problem in one line."""

from __future__ import annotations

MAX_MAGNITUDE = 1e6  # any number of a user's file (metres, seconds, gains): |x| <= 1e6
MAX_LINE_CHARS = 299  # an error line stays under 300 characters (a 10 MB value: an excerpt)
_EXCERPT_CHARS = 60


def excerpt(value, limit: int = _EXCERPT_CHARS) -> str:
    """``repr(value)`` on one line, cut to about ``limit`` characters with its full length named
    (``'xxxxxxxx...' (10000002 chars)``): what an error message shows of a user's value.
    """
    if isinstance(value, (str, bytes)) and len(value) > limit:
        text, size = repr(value[:limit]), len(value)  # never repr a huge string whole
    else:
        text = ' '.join(repr(value).split())
        size = len(text) if len(text) > limit else None
    text = ' '.join(text.split())
    if size is not None:
        text = f'{text[: limit - 3]}...'
    return text if size is None else f'{text} ({size} chars)'


def one_line(text: str, limit: int = MAX_LINE_CHARS) -> str:
    """``text`` on one line (whitespace runs become one space), cut to ``limit`` characters."""
    text = ' '.join(str(text).split())
    return text if len(text) <= limit else f'{text[: limit - 3]}...'


def _path_tail(path: str, limit: int = 100) -> str:
    """A file's path on one line of at most ``limit`` characters, cut at its start: the end
    (the file's name) is what the reader needs.
    """
    text = ' '.join(str(path).split())
    return text if len(text) <= limit else f'...{text[3 - limit:]}'


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
        """``FILE: FIELD: problem`` on one line of at most :data:`MAX_LINE_CHARS` characters."""
        parts = [_path_tail(self.file)] if self.file else []
        parts += [one_line(self.field, 100)] if self.field else []
        return one_line(': '.join(parts + [str(self.problem)]), MAX_LINE_CHARS)

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
