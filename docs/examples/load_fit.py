# %% [markdown]
# # Loading ccdpsf outputs in Python
#
# A notebook-style script (cells marked `# %%`; Jupyter, VS Code and Spyder run them one by
# one). It reads a fit, draws a corner plot of the shared PSF parameters with matplotlib
# alone, and reads a trend's relation table. Set-up: the README's, then
#
#     CCDPSF_FIT=out/fit CCDPSF_TREND=out/campaign PYTHONPATH=python /usr/bin/python3 docs/examples/load_fit.py
#
# where out/fit is a `ccdpsf fit` folder and out/campaign a `ccdpsf trend` folder (e.g. the
# one `bash tools/bootstrap.sh demo` writes). The corner plot goes to CCDPSF_PLOT_DIR (default:
# a new temporary folder).

# %%
import os
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no window
import matplotlib.pyplot as plt
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "python"))
import ccdpsf  # noqa: E402  (the package lives in python/ of this repository)

fit_folder = Path(os.environ.get("CCDPSF_FIT", "out/fit"))
trend_folder = Path(os.environ.get("CCDPSF_TREND", "out/campaign"))
plot_dir = Path(os.environ.get("CCDPSF_PLOT_DIR") or tempfile.mkdtemp(prefix="ccdpsf_"))

# %% [markdown]
# ## The fit: summary, chain and table

# %%
fit = ccdpsf.read_fit(fit_folder)
print(fit)
print("verdict:", fit.verdict)
chain = fit.get_chain()  # (steps, walkers, parameters), burn-in dropped
print("chain:", chain.shape, "parameters:", fit.names)
draws = fit.table  # astropy QTable with units: one row per post-burn-in draw
print(draws[["walker", "step", "log_prob", "flux_e"]][:3])

# %% [markdown]
# ## A corner plot: the PSF parameters every exposure shares
#
# Diagonal: each parameter's histogram with its 16 / 50 / 84 % quantiles (dashed / solid /
# dashed). Below it: the 2-D histogram of each pair.

# %%
shared = [n for n in ("flux_e", "airy_radius_px", "defocus_sigma_px", "ccd_sigma_x_px",
                      "ccd_sigma_y_px") if n in fit.names]
flat = fit.get_chain(flat=True)
columns = [flat[:, fit.names.index(n)] for n in shared]
units = fit.units


def corner(columns, labels, bins=30):
    n = len(columns)
    figure, axes = plt.subplots(n, n, figsize=(2.2 * n, 2.2 * n), squeeze=False)
    ranges = [np.percentile(c, [0.5, 99.5]) for c in columns]
    for row in range(n):
        for col in range(n):
            ax = axes[row, col]
            if col > row:
                ax.set_visible(False)
                continue
            if row == col:
                ax.hist(columns[col], bins=bins, range=ranges[col], histtype="step",
                        color="k")
                q16, q50, q84 = np.percentile(columns[col], [16, 50, 84])
                for q, style in ((q16, "--"), (q50, "-"), (q84, "--")):
                    ax.axvline(q, color="tab:blue", linestyle=style, linewidth=1)
                ax.set_yticks([])
            else:
                ax.hist2d(columns[col], columns[row], bins=bins,
                          range=[ranges[col], ranges[row]], cmap="Greys")
            if row == n - 1:
                ax.set_xlabel(labels[col], fontsize=8)
            else:
                ax.set_xticklabels([])
            if col == 0 and row > 0:
                ax.set_ylabel(labels[row], fontsize=8)
            elif col > 0 or row == 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=6)
            ax.tick_params(axis="x", labelrotation=45)
    figure.subplots_adjust(wspace=0.05, hspace=0.05)
    return figure


labels = [f"{n} [{units[n].to_string()}]" if units[n].to_string() else n for n in shared]
figure = corner(columns, labels)
corner_png = plot_dir / "corner.png"
figure.savefig(corner_png, dpi=90, bbox_inches="tight")
plt.close(figure)
print("corner plot:", corner_png)

# %% [markdown]
# ## The trend: a relation table and the requirements

# %%
trend = ccdpsf.read_trend(trend_folder)
print(trend)
relation = trend.relations["fwhm_um_vs_wavelength"]
print(relation)
print(trend.requirements[["name", "value", "unit", "verdict"]])
