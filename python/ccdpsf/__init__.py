"""Read ccdpsf's output folders from Python, and run ccdpsf from a notebook.

    import ccdpsf
    fit = ccdpsf.read_fit("out/fit")          # fit.json, chain.fits, residuals.fits
    fit.get_chain()                           # (steps, walkers, parameters), after burn-in
    trend = ccdpsf.read_trend("out/campaign") # trend.json, every CSV, groups/ lazily
    diag = ccdpsf.read_diagnose("out/diag")   # diagnose.json's rounds
    grid = ccdpsf.read_grid("out/grid")       # psf_map, catalogue, relations as QTables
    fit = ccdpsf.run("fit", *files, out="out/fit", joint=True, target_ess=200)

See python/README.md.
"""

from .diagnose_result import read_diagnose
from .errors import NoChainError, OutputFormatError, OutputMissingError, RunError
from .fit_result import Covariance, FitResult, read_fit
from .grid_result import GridResult, read_grid
from .runner import run
from .trend_result import TrendResult, read_trend

__all__ = [
    "Covariance", "FitResult", "GridResult", "NoChainError", "OutputFormatError", "OutputMissingError",
    "RunError", "TrendResult", "read_diagnose", "read_fit", "read_grid", "read_trend", "run",
]
