"""Shared fixtures: the package on sys.path, writers of synthetic ccdpsf outputs, and the real
binary's outputs (made once per session; skipped without CCDPSF_BINARY)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

PYTHON_DIR = Path(__file__).resolve().parents[1]
REPO_DIR = PYTHON_DIR.parent
sys.path.insert(0, str(PYTHON_DIR))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def binary_or_skip():
    binary = os.environ.get("CCDPSF_BINARY")
    if not binary:
        pytest.skip("CCDPSF_BINARY is not set: the end-to-end tests need the built ccdpsf "
                    "(ctest sets it; by hand: CCDPSF_BINARY=build/ccdpsf)")
    if not os.access(binary, os.X_OK):
        pytest.fail(f"CCDPSF_BINARY={binary} is not an executable")
    return binary


def run_binary(binary, *args):
    result = subprocess.run([binary, *args], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f"ccdpsf {' '.join(args)} failed:\n{result.stderr}"
    return result


@pytest.fixture(scope="session")
def ccdpsf_binary():
    return binary_or_skip()


@pytest.fixture(scope="session")
def simulated_exposures(ccdpsf_binary, tmp_path_factory):
    """Two exposures of the demo simulation (the paper's PSF, known truth)."""
    out = tmp_path_factory.mktemp("e2e") / "sim"
    run_binary(ccdpsf_binary, "simulate", f"--config={REPO_DIR / 'testdata/demo_simulation.json'}",
               f"--out={out}")
    return sorted(out.glob("exposure_*.fits"))[:2]


@pytest.fixture(scope="session")
def real_fit_folder(ccdpsf_binary, simulated_exposures, tmp_path_factory):
    """A joint fit with a short MCMC (400 steps: not converged, which does not matter for
    checking that the files agree with each other)."""
    out = tmp_path_factory.mktemp("e2e") / "fit"
    run_binary(ccdpsf_binary, "fit", "--joint", "--max_steps=400", "--target_ess=100",
               f"--out={out}", *map(str, simulated_exposures))
    return out


@pytest.fixture(scope="session")
def real_trend_folder(ccdpsf_binary, tmp_path_factory):
    """The bundled small campaign with a short MCMC per group (about 10 s on two cores)."""
    out = tmp_path_factory.mktemp("e2e") / "trend"
    run_binary(ccdpsf_binary, "trend", "--max_steps=300", "--target_ess=50", f"--out={out}",
               str(REPO_DIR / "testdata/campaign_small"))
    return out
