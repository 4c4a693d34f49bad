"""Reports on softsim's numerics.

``stability``: the ``softsim stability`` report (stress catalogue for every material model, the
measured stability limit against ``dt: auto``, a CSV table and a PNG plot); ``catalogue``: its
stress scenes, generated in code; ``limits``: the measurement of the largest stable step.
"""

from .catalogue import MODELS, CatalogueScene, catalogue
from .limits import LimitCase, LimitMeasurement, measure_limit
from .stability import CatalogueRow, StabilityReport, stability_report

__all__ = ["MODELS", "CatalogueRow", "CatalogueScene", "LimitCase", "LimitMeasurement", "StabilityReport",
           "catalogue", "measure_limit", "stability_report"]
