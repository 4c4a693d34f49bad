"""Parameter sweeps on Dask (``softsim sweep``).

``spec`` reads and validates a sweep file and expands it into runs, each a re-validated scene;
``runner`` runs them on a local or remote Dask cluster and writes one HDF5 file per run and a
summary table; ``metrics`` reads a run's summary row back from its file; ``plot`` draws the table.
Dask is imported only when runs are submitted (``pip install ".[sweep]"`` in softsim's folder).
"""

from .metrics import METRIC_COLUMNS, run_metrics, tip_vertices
from .plot import plot_summary, read_summary
from .runner import SweepResult, local_client, local_layout, plan_runs, remote_client, run_sweep
from .spec import Run, Sweep, expand_sweep, load_sweep, parse_sweep

__all__ = [
    "METRIC_COLUMNS",
    "Run",
    "Sweep",
    "SweepResult",
    "expand_sweep",
    "load_sweep",
    "local_client",
    "local_layout",
    "parse_sweep",
    "plan_runs",
    "plot_summary",
    "read_summary",
    "remote_client",
    "run_metrics",
    "run_sweep",
    "tip_vertices",
]
