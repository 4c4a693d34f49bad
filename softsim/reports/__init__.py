"""Reports on softsim's numerics (``softsim stability``)."""
