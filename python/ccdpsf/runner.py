"""run(): the ccdpsf binary from Python, returning the matching reader's object."""

import math
import numbers
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

from .diagnose_result import read_diagnose
from .errors import RunError
from .fit_result import fit_subfolders, read_fit
from .grid_result import read_grid
from .trend_result import read_trend


def find_binary(binary=None):
    """The ccdpsf executable: the argument, else $CCDPSF_BINARY, else `ccdpsf` on PATH."""
    candidate = binary or os.environ.get("CCDPSF_BINARY") or shutil.which("ccdpsf")
    if not candidate:
        raise FileNotFoundError("no ccdpsf binary: pass binary=..., set CCDPSF_BINARY, or put "
                                "ccdpsf on PATH (it is build/ccdpsf after the README's set-up)")
    path = Path(candidate)
    if not path.is_file() or not os.access(path, os.X_OK):
        raise FileNotFoundError(f"ccdpsf binary {str(path)!r} is not an executable file")
    return str(path)


def flag(key, value):
    """One command-line flag: True -> --key, False -> --nokey, a list -> --key=a,b,...;
    floats keep every digit (repr), paths are written as paths. None gives no flag."""
    if not key.isidentifier():
        raise ValueError(f"option name {key!r}: ccdpsf options are letters, digits and '_'")
    if value is None:
        return None
    if isinstance(value, bool):
        return f"--{key}" if value else f"--no{key}"
    if isinstance(value, (list, tuple)):
        return f"--{key}=" + ",".join(_text(v) for v in value)
    return f"--{key}={_text(value)}"


def _text(value):
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral):
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"option value {value}: ccdpsf takes finite numbers")
        return repr(value)
    return str(value)


def command_line(command, files, out, options, binary):
    args = [binary, command]
    if out is not None:
        args.append(flag("out", out))
    for key, value in options.items():
        text = flag(key, value)
        if text is not None:
            args.append(text)
    args.extend(os.fspath(f) for f in files)
    return args


def error_line(stderr):
    """The one-line error ccdpsf printed ('ccdpsf: error: ...'), else stderr's last line."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    for line in reversed(lines):
        if line.startswith("ccdpsf: error:"):
            return line[len("ccdpsf: error:"):].strip()
    return lines[-1] if lines else "(nothing on stderr)"


def run(command, *files, out=None, binary=None, echo=False, timeout=None, **options):
    """Run ``ccdpsf COMMAND --out=OUT --key=value ... FILES`` and read what it wrote.

    options: ccdpsf's flags by name (``joint=True`` -> --joint, ``mcmc=False`` -> --nomcmc,
    ``target_ess=200`` -> --target_ess=200). binary: the executable (else $CCDPSF_BINARY, else
    ccdpsf on PATH). echo: copy ccdpsf's stderr (progress, notes) to sys.stderr as it comes.
    timeout: seconds, then the run is killed (subprocess.TimeoutExpired).

    Returns: fit -> FitResult (several files without --joint: dict subfolder name ->
    FitResult); trend -> TrendResult; diagnose -> Diagnosis; grid -> GridResult; other commands -> the output
    folder as a Path (or stdout's text without out). Raises RunError (exit_code, message,
    stderr) when ccdpsf exits non-zero.
    """
    args = command_line(command, files, out, options, find_binary(binary))
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               stdin=subprocess.DEVNULL, text=True, errors="replace")
    stdout_parts = []
    reader = threading.Thread(target=lambda: stdout_parts.append(process.stdout.read()))
    reader.start()
    stderr_lines = []
    timer, timed_out = None, threading.Event()

    def kill():
        timed_out.set()
        process.kill()

    if timeout is not None:
        timer = threading.Timer(timeout, kill)
        timer.start()
    try:
        for line in process.stderr:
            stderr_lines.append(line)
            if echo:
                sys.stderr.write(line)
        code = process.wait()
    finally:
        if timer is not None:
            timer.cancel()
        reader.join()
        process.stdout.close()
        process.stderr.close()
    stderr = "".join(stderr_lines)
    if timed_out.is_set():
        raise subprocess.TimeoutExpired(args, timeout, output="".join(stdout_parts),
                                        stderr=stderr)
    if code != 0:
        raise RunError(error_line(stderr), code, args, stderr)
    if out is None:
        return "".join(stdout_parts)
    out = Path(out)
    if command == "fit":
        if (out / "fit.json").is_file():
            return read_fit(out)
        return {p.name: read_fit(p) for p in fit_subfolders(out)}
    if command == "trend":
        return read_trend(out)
    if command == "grid":
        return read_grid(out)
    if command == "diagnose":
        return read_diagnose(out)
    return out
