"""The ``softsim`` command line (installed as ``softsim.cli``): parses, validates, calls the library."""
