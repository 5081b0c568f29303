"""One error type for bad scenes, one for bad options, and the one-line warning format.

Both errors carry enough context for the CLI to print a single line naming *what* is wrong and
*where* (file, line, element), then exit with status 2.
"""
from __future__ import annotations

import warnings


class Links1Error(ValueError):
    """Base class of the errors the CLI reports in one line (exit status 2)."""


class SceneError(Links1Error):
    """A scene that cannot be loaded: malformed XML, an unknown plugin, a bad value.

    Parameters
    ----------
    message : str
        What is wrong, e.g. ``"radius must be > 0, got -1"``.
    file : str, optional
        The scene file (or included file) the element comes from.
    line : int, optional
        1-based line of the element in ``file``.
    element : str, optional
        A short description of the element, e.g. ``"<shape type='sphere' id='ball'>"``.
    """

    def __init__(self, message: str, file: str | None = None, line: int | None = None,
                 element: str | None = None):
        self.message = message
        self.file = file
        self.line = line
        self.element = element
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.file is not None:
            where = f"{self.file}:{self.line}: " if self.line is not None else f"{self.file}: "
        elem = f"{self.element}: " if self.element else ""
        return f"{where}{elem}{self.message}"


class UsageError(Links1Error):
    """A bad command-line or API option (e.g. ``--spp 0``)."""


class RenderAborted(RuntimeError):
    """A render that cannot finish, e.g. too many worker processes died.

    The CLI prints it in one line and exits with status 1, writing no output.
    """


def format_warning(message, category, filename, lineno, line=None) -> str:
    """Every warning as one line, ``links1: warning: FILE:LINE: ...`` for scene warnings
    (never Python's format with the source line of links1 that issued it)."""
    return f"links1: warning: {message}\n"


def one_line_warnings() -> None:
    """Print warnings as :func:`format_warning` does, in this process (the CLI, its workers);
    Mitsuba's own log warnings join them through :func:`links1_app.renderers.renderer_warnings`."""
    warnings.formatwarning = format_warning
