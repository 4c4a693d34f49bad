"""Verification cases with analytic answers: error against run time (softsim verify).

- ``references``: the analytic answers from a scene's parameters, Richardson extrapolation and
  observed orders;
- ``driver``: one scene prepared by the library and stepped in timed chunks (``Run``);
- ``cases``: the cases (cantilever, axial vibration, traction, rigid motion, patch, energy), each
  over ladders of element size and time step for every material model (``CASES``);
- ``report``: the CSV, the terminal table, one plot per case and ``verify.md`` (``verify_report``).
"""

from .cases import CASES, VerifyRow
from .report import VerifyReport, verify_report

__all__ = ["CASES", "VerifyReport", "VerifyRow", "verify_report"]
