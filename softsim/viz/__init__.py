"""Looking at results: info, plots, export and rendering of softsim output files."""
