"""Exceptions raised by the ccdpsf readers and by run()."""


class OutputMissingError(FileNotFoundError):
    """A ccdpsf output folder lacks a file the reader needs (e.g. fit.json)."""


class NoChainError(OutputMissingError):
    """The fit has no MCMC chain: it ran with --nomcmc, so chain.fits was not written."""


class OutputFormatError(ValueError):
    """A ccdpsf output file is there but does not hold what its format promises."""


class RunError(RuntimeError):
    """The ccdpsf binary exited with a non-zero code.

    Attributes: ``exit_code`` (1 bad input, 2 usage error, 3 --strict verdict, negative for a
    signal), ``message`` (the one-line error ccdpsf printed), ``command`` (the argument list),
    ``stderr`` (everything it printed on stderr).
    """

    def __init__(self, message, exit_code, command, stderr):
        super().__init__(f"ccdpsf exited with code {exit_code}: {message}")
        self.message = message
        self.exit_code = exit_code
        self.command = command
        self.stderr = stderr
