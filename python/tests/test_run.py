"""run() against a stand-in binary (a shell script that records its arguments and exits as
told), so flag building and error reporting are checked without the real tool."""

import os
import stat

import pytest

import ccdpsf
from ccdpsf.runner import flag

FAKE = """#!/bin/sh
printf '%s\\n' "$@" > "$(dirname "$0")/args.txt"
echo "ccdpsf: note: something said on the way" >&2
if [ -n "$FAKE_EXIT" ]; then
  echo "ccdpsf: error: --walkers = -3 is outside 0 (automatic) to 100000" >&2
  exit "$FAKE_EXIT"
fi
echo "printed on stdout"
"""


@pytest.fixture
def fake_binary(tmp_path):
    path = tmp_path / "bin" / "ccdpsf"
    path.parent.mkdir()
    path.write_text(FAKE)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_flags():
    assert flag("joint", True) == "--joint"
    assert flag("mcmc", False) == "--nomcmc"
    assert flag("target_ess", 200) == "--target_ess=200"
    assert flag("pixel_um", 0.1 + 0.2) == "--pixel_um=0.30000000000000004"  # every digit
    assert flag("keywords", ["gain_e_per_adu=EGAIN", "exptime_s=EXPMS*0.001"]) == \
        "--keywords=gain_e_per_adu=EGAIN,exptime_s=EXPMS*0.001"
    assert flag("seed", None) is None
    with pytest.raises(ValueError):
        flag("bad-name", 1)
    with pytest.raises(ValueError):
        flag("pixel_um", float("nan"))


def test_run_passes_arguments_in_order(fake_binary, tmp_path):
    out = ccdpsf.run("gain", tmp_path / "a.fits", "b.fits", out=tmp_path / "o",
                     binary=str(fake_binary), exptime_s=1.5, strict=True, mcmc=False, seed=None)
    assert out == tmp_path / "o"  # no reader for gain: the folder
    args = (fake_binary.parent / "args.txt").read_text().splitlines()
    assert args == ["gain", f"--out={tmp_path / 'o'}", "--exptime_s=1.5", "--strict",
                    "--nomcmc", str(tmp_path / "a.fits"), "b.fits"]
    assert ccdpsf.run("help", binary=str(fake_binary)) == "printed on stdout\n"


@pytest.mark.parametrize("code", [1, 2, 3])
def test_run_failure_carries_message_and_code(fake_binary, tmp_path, monkeypatch, code):
    monkeypatch.setenv("FAKE_EXIT", str(code))
    with pytest.raises(ccdpsf.RunError) as info:
        ccdpsf.run("fit", "x.fits", out=tmp_path / "o", binary=str(fake_binary), walkers=-3)
    assert info.value.exit_code == code
    assert info.value.message == "--walkers = -3 is outside 0 (automatic) to 100000"
    assert "something said on the way" in info.value.stderr
    assert info.value.command[-1] == "x.fits"


def test_binary_from_environment(fake_binary, tmp_path, monkeypatch):
    monkeypatch.setenv("CCDPSF_BINARY", str(fake_binary))
    assert ccdpsf.run("simulate", out=tmp_path / "s") == tmp_path / "s"
    monkeypatch.setenv("CCDPSF_BINARY", str(tmp_path / "missing"))
    with pytest.raises(FileNotFoundError, match="not an executable"):
        ccdpsf.run("simulate", out=tmp_path / "s")
    monkeypatch.delenv("CCDPSF_BINARY")
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(FileNotFoundError, match="CCDPSF_BINARY"):
        ccdpsf.run("simulate", out=tmp_path / "s")
