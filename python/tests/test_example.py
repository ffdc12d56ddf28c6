"""docs/examples/load_fit.py runs on a fit and a trend made by the real binary in this session
and writes a corner plot (skipped without CCDPSF_BINARY)."""

import os
import subprocess
import sys

import numpy as np
from conftest import REPO_DIR


def test_load_fit_example_runs(real_fit_folder, real_trend_folder, tmp_path):
    env = dict(os.environ, CCDPSF_FIT=str(real_fit_folder), CCDPSF_TREND=str(real_trend_folder),
               CCDPSF_PLOT_DIR=str(tmp_path), MPLCONFIGDIR=str(tmp_path / "mpl"))
    result = subprocess.run([sys.executable, str(REPO_DIR / "docs/examples/load_fit.py")],
                            env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    png = tmp_path / "corner.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # A drawn figure, not a blank canvas: many distinct pixel values.
    import matplotlib.image
    image = matplotlib.image.imread(png)
    assert len(np.unique(image.reshape(-1, image.shape[-1]), axis=0)) > 20
    # The trend cell printed the relation table: its group labels are in the output.
    assert "f00_600nm_160200e_focus" in result.stdout
    assert "corner plot:" in result.stdout
