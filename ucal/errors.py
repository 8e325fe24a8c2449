"""Typed errors of the application layer and the exit codes of SPEC.md they map to."""

from __future__ import annotations

from typing import Any

EXIT_OK = 0
EXIT_OUT_OF_TOLERANCE = 1
EXIT_USAGE = 2
EXIT_HARDWARE = 3
EXIT_SAFETY = 4
EXIT_INTERRUPTED = 130


class UcalError(Exception):
    """Base of every error the CLI turns into a one-line message and an exit code."""

    exit_code = EXIT_USAGE


class InputError(UcalError):
    """Bad flag, unreadable or invalid profile/world file; the message names file and key."""

    exit_code = EXIT_USAGE


class ProfileError(InputError):
    """A profile or world file that cannot be read or does not validate."""

    def __init__(self, path: object, key: str | None, message: str):
        self.path = str(path)
        self.key = key
        where = f"{self.path}: {key}" if key else self.path
        super().__init__(f"{where}: {message}")


class SafetyError(UcalError):
    """Refused for safety: out of joint range, unreachable, too close to a singularity."""

    exit_code = EXIT_SAFETY


class UnreachableError(SafetyError):
    """No joint solution reaches the requested pose inside the joint ranges."""


class NotConfirmed(UcalError):
    """The operator declined the confirmation before the first motion: refused (exit 4);
    nothing moved, nothing written."""

    exit_code = EXIT_SAFETY


class HardwareError(UcalError):
    """Hardware or communication fault; the message names the device."""

    exit_code = EXIT_HARDWARE


class OutOfToleranceError(UcalError):
    """The run finished but its result is outside tolerance.

    ``result`` is the run's result object: with ``--json`` the CLI prints it with the error
    fields added (SPEC.md: exit 1 is a result).
    """

    exit_code = EXIT_OUT_OF_TOLERANCE

    def __init__(self, message: str, result: dict[str, Any] | None = None):
        super().__init__(message)
        self.result = result


class InterruptedAfterResult(UcalError):
    """A signal came once the robot had stopped and the run had begun to write its result: the
    result stands (written or not, as ``result`` says) and the run ends as interrupted.

    ``result`` is the run's result object: with ``--json`` the CLI prints it with the error
    fields added, as for a result out of tolerance.
    """

    exit_code = EXIT_INTERRUPTED

    def __init__(self, result: dict[str, Any]):
        written = bool(result.get("written"))
        super().__init__(
            "interrupted as the run ended, the robot stopped: "
            + (
                "its result was written and stands as reported"
                if written
                else "nothing was written; its result is reported"
            )
        )
        self.result = result
