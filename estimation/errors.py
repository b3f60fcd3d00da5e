"""Exceptions raised on input that cannot be read or estimated from."""

from __future__ import annotations


class BonefitError(ValueError):
    """Base class: a problem with the caller's input, with where it is.

    Parameters
    ----------
    detail : str
        One sentence saying what is wrong, naming the field, line or sensor.
    field, sensor : str, optional
        The column, parameter or sensor concerned.
    line, column : int, optional
        1-based position in a text file.
    """

    title = "Invalid input"

    def __init__(
        self,
        detail: str,
        *,
        field: str | None = None,
        sensor: str | None = None,
        line: int | None = None,
        column: int | None = None,
    ) -> None:
        super().__init__(detail)
        self.detail = detail
        self.field = field
        self.sensor = sensor
        self.line = line
        self.column = column

    def location(self) -> dict[str, str | int]:
        """The non-empty location fields, for error reports."""
        found = {"field": self.field, "sensor": self.sensor, "line": self.line,
                 "column": self.column}
        return {k: v for k, v in found.items() if v is not None}


class InputError(BonefitError):
    """The input is malformed: unreadable file, unknown column, bad number, missing sensor."""

    title = "Malformed input"


class EstimationError(BonefitError):
    """The input is well formed but the quantity cannot be estimated from it.

    Examples: too little motion to locate a joint, all samples of a sensor missing,
    bone lengths outside human range (wrong units).
    """

    title = "Cannot estimate from this input"


class LimitError(InputError):
    """The input declares or holds more than a documented limit allows (frames, columns,
    line length, array size); ``limit`` names the limit (``MAX_FRAMES``...)."""

    title = "Input beyond a limit"

    def __init__(self, detail: str, *, limit: str, field: str | None = None,
                 sensor: str | None = None, line: int | None = None,
                 column: int | None = None) -> None:
        super().__init__(detail, field=field, sensor=sensor, line=line, column=column)
        self.limit = limit

    def location(self) -> dict[str, str | int]:
        """The location fields and the name of the limit."""
        return {**super().location(), "limit": self.limit}
