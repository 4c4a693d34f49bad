"""Parameter sweeps on Dask (softsim sweep)."""
