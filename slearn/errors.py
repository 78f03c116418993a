"""Every error slearn raises on purpose derives from :class:`SlearnError`.

Messages name the file, channel or field at fault and say what to do. The CLI maps
the classes to exit codes; nothing else calls ``sys.exit``.
"""


class SlearnError(Exception):
    """Base class of slearn's errors; the CLI exits 1 on it."""

    exit_code = 1


class ParameterError(SlearnError, ValueError):
    """A parameter of the core (a length, a bound, a scoring rule) is out of its range."""


class InputError(SlearnError):
    """A file, channel, field or option the user gave cannot be used."""


class SpecError(InputError):
    """A channel spec is malformed or does not fit the logs."""


class DecodeError(InputError):
    """A channel has no usable decoder, or a payload does not decode."""


class FieldPathError(SpecError):
    """A field path is malformed or names a field the message type does not have."""


class LibraryFormatError(InputError):
    """A file is not a readable slearn pattern library."""


class TruncatedLogWarning(UserWarning):
    """A log ended early; what could be salvaged was used (the CLI exits 3)."""


class DataWarning(UserWarning):
    """The data or the spec could make a result mean less than it seems (the CLI prints it)."""
