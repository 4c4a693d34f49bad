"""The ``softsim`` console script.  Loading the commands (click, NumPy, Numba, LLVM) takes about
half a second; a Ctrl-C meanwhile ends the command as one later does: ``softsim: interrupted``
and exit code 130, not a traceback from inside an import."""

import sys

EXIT_INTERRUPTED = 130      # the exit code of a command ended by Ctrl-C or SIGTERM (every command's)


def main():
    try:
        from .main import main as softsim_main
    except KeyboardInterrupt:
        sys.stderr.write("softsim: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    softsim_main()
