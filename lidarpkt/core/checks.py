"""The allowed values of an option, declared once and checked in both places an option is given: a keyword
of the Python API (:meth:`Allowed.check`, a Python value) and a command-line flag (:meth:`Allowed.parse`,
its text). Both raise one :class:`~lidarpkt.errors.UsageError` naming the option as the caller wrote it
(``cut_angle_deg=400`` or ``--grid 1e-9``), what it takes and an example.

``Number`` is a number in a range (whole or not, ends open or closed, odd); ``Switch`` a ``bool``; ``Text`` a
string; ``Several`` one or several values each of which must pass another check (a lone value is one item).
``None`` passes wherever an option's default is ``None`` (``optional=True``).

:meth:`Allowed.bad_values` gives texts that the check refuses (below, above, not a number...): the tests
drive every flag with them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from lidarpkt.errors import UsageError

__all__ = ["Allowed", "Number", "Switch", "Text", "Several", "option_error", "WORKERS", "PORT"]


def option_error(name: str, value: Any, what: str, example: str, *, flag: bool) -> UsageError:
    """The one error of a bad option value: ``--flag VALUE: <what>; give e.g. --flag EXAMPLE`` on the command
    line, ``name=VALUE: <what>; give e.g. name=EXAMPLE`` in the API."""
    if flag:
        return UsageError(f"{name} {value}: {what}; give e.g. {name} {example}")
    return UsageError(f"{name}={value!r}: {what}; give e.g. {name}={example}")


class Allowed:
    """What an option takes (a subclass per kind). ``optional``: ``None`` passes (the option's default)."""

    optional: bool = False
    example: str = ""

    def check(self, value: Any, name: str) -> Any:
        """``value`` (a Python object) if it is allowed, as the option's type. Raises :class:`UsageError`."""
        raise NotImplementedError

    def parse(self, text: str, flag: str) -> Any:
        """``text`` (a command-line value) as the option's type. Raises :class:`UsageError`."""
        raise NotImplementedError

    def bad_values(self) -> list[str]:
        """Command-line texts this check refuses."""
        return []


@dataclass(frozen=True)
class Number(Allowed):
    """A number: ``whole`` (an int) or not (a float; NaN and infinities refused), from ``low`` to ``high``
    (``None``: unbounded), each end excluded where ``*_open``; ``odd`` whole numbers only."""

    low: float | None = None
    high: float | None = None
    whole: bool = False
    low_open: bool = False
    high_open: bool = False
    odd: bool = False
    example: str = "1"
    optional: bool = False
    unit: str = ""

    def describe(self) -> str:
        """``"a whole number >= 1"``, ``"a number in [0, 360)"``..."""
        kind = ("an odd whole number" if self.odd else "a whole number") if self.whole else "a number"
        lo, hi = _fmt(self.low), _fmt(self.high)
        if self.low is not None and self.high is not None:
            text = f"{kind} in {'(' if self.low_open else '['}{lo}, {hi}{')' if self.high_open else ']'}"
        elif self.low is not None:
            text = f"{kind} {'>' if self.low_open else '>='} {lo}"
        elif self.high is not None:
            text = f"{kind} {'<' if self.high_open else '<='} {hi}"
        else:
            text = kind
        return f"{text} {self.unit}".rstrip()

    def _inside(self, value: float) -> bool:
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        if self.high is not None and (value >= self.high if self.high_open else value > self.high):
            return False
        return not (self.odd and int(value) % 2 == 0)

    def check(self, value: Any, name: str) -> Any:
        if value is None and self.optional:
            return None
        whole_ok = isinstance(value, int) or (hasattr(value, "dtype") and getattr(value.dtype, "kind", "") in "iu")
        number_ok = whole_ok or isinstance(value, float) or (hasattr(value, "dtype") and value.dtype.kind == "f")
        if isinstance(value, bool) or not number_ok or (self.whole and not whole_ok):
            raise option_error(name, value, f"not {self.describe()}", self.example, flag=False)
        number = int(value) if self.whole else float(value)
        if not self.whole and not math.isfinite(number):
            raise option_error(name, value, f"not {self.describe()}", self.example, flag=False)
        if not self._inside(number):
            raise option_error(name, value, f"out of range; {name} takes {self.describe()}", self.example, flag=False)
        return number

    def parse(self, text: str, flag: str) -> Any:
        try:
            number: float = int(text) if self.whole else float(text)
        except ValueError:
            raise option_error(flag, text, f"not {self.describe()}", self.example, flag=True) from None
        if not self.whole and not math.isfinite(number):
            raise option_error(flag, text, f"not {self.describe()}", self.example, flag=True)
        if not self._inside(number):
            raise option_error(flag, text, f"out of range; {flag} takes {self.describe()}", self.example, flag=True)
        return number

    def bad_values(self) -> list[str]:
        bad = ["abc", "nan" if not self.whole else "1.5"]
        if self.low is not None:
            bad.append(_fmt(self.low - (0 if self.low_open else (1 if self.whole else max(abs(self.low) * 1e-3, 1e-9)))))
        if self.high is not None:
            bad.append(_fmt(self.high + (0 if self.high_open else (1 if self.whole else max(abs(self.high) * 1e-3, 1e-9)))))
        if self.odd:
            bad.append(_fmt((self.low or 0) + 1 if int(self.low or 0) % 2 else (self.low or 0)))
        return bad


@dataclass(frozen=True)
class Switch(Allowed):
    """``True`` or ``False`` (not a truthy string: ``include_partial='no'`` is refused)."""

    optional: bool = False
    example: str = "True"

    def check(self, value: Any, name: str) -> Any:
        if value is None and self.optional:
            return None
        if isinstance(value, bool) or (hasattr(value, "dtype") and value.dtype.kind == "b"):
            return bool(value)
        what = "True, False or None" if self.optional else "True or False"
        raise option_error(name, value, f"not {what}", self.example, flag=False)


@dataclass(frozen=True)
class Text(Allowed):
    """A string."""

    optional: bool = False
    example: str = "'name'"

    def check(self, value: Any, name: str) -> Any:
        if value is None and self.optional:
            return None
        if isinstance(value, str):
            return value
        raise option_error(name, value, "not a string", self.example, flag=False)


@dataclass(frozen=True)
class Several(Allowed):
    """One or several values (a list, tuple, set...; a lone value is one), each allowed by ``item``: the
    tuple of them."""

    item: Allowed = Text()
    optional: bool = True
    example: str = "[1]"

    def check(self, value: Any, name: str) -> Any:
        if value is None and self.optional:
            return None
        if isinstance(value, (str, bytes, int, float)) or not hasattr(value, "__iter__"):
            value = [value]  # one value where several may be given
        try:
            items = list(value)
        except TypeError:
            raise option_error(name, value, "not a list of values", self.example, flag=False) from None
        checked = []
        for v in items:
            try:
                checked.append(self.item.check(v, name))
            except UsageError:
                describe = getattr(self.item, "describe", None)
                what = describe() if describe else "of the wrong type"
                raise option_error(name, value, f"holds {v!r}; each item must be {what}", self.example,
                                   flag=False) from None
        return tuple(checked)


#: the options several layers take, declared once: the CPU cores a job may use, a UDP port
WORKERS = Number(1, 1024, whole=True, example="2")
PORT = Number(1, 65535, whole=True, example="2368")


def _fmt(x: float | None) -> str:
    if x is None:
        return ""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"
