"""Exceptions raised by softsim.

The library raises these; only the command line turns them into a one-line message and an exit
code.  Each message is complete on its own: it names the key or file, the value, and what is
allowed.
"""


class SoftsimError(Exception):
    """Base class of every error softsim raises on purpose.

    Its text is always one line: line breaks that come from user input (a YAML key with a newline,
    a library's multi-line message) are shown escaped.
    """

    def __str__(self):
        return super().__str__().replace("\r", "\\r").replace("\n", "\\n")


class ConfigError(SoftsimError):
    """A scene file or an override is invalid (unknown key, wrong type, value out of range)."""


class MeshError(SoftsimError):
    """A mesh cannot be simulated (unreadable, no tetrahedra, degenerate or tangled elements)."""


class MissingDependencyError(SoftsimError):
    """An optional Python extra or a system library needed for this command is not installed."""


# What installs the plotting and rendering extra (quoted: zsh would glob the brackets).  softsim
# is installed from its source folder (it is not on PyPI), so the extra is installed from there.
PLOT_EXTRA = 'pip install ".[plot]" in softsim\'s source folder'


class SimulationError(SoftsimError):
    """A run could not go on (e.g. the output file cannot be written)."""
