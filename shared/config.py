"""Strict reading of YAML-derived dicts into typed values.

Every scenario and planner parameter goes through :class:`Section`, so that a bad file always fails
the same way: the file, the key path, the offending value and what was expected, e.g.

    configs/scenarios/navigation.yaml: robot.model: unknown robot 'pointbot'
    (got 'pointbot'; expected one of: diff_drive, panda, point_robot)

Unknown keys are errors (a typo must never silently fall back to a default).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

_MISSING = object()


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type or range."""

    def __init__(
        self,
        source: str,
        path: str,
        message: str,
        value: Any = _MISSING,
        expected: str | None = None,
    ):
        self.source, self.path, self.message = source, path, message
        self.value, self.expected = value, expected
        where = f"{source}: {path}" if path else source
        text = f"{where}: {message}"
        extra = []
        if value is not _MISSING:
            extra.append(f"got {value!r}")
        if expected:
            extra.append(f"expected {expected}")
        if extra:
            text += f" ({'; '.join(extra)})"
        super().__init__(text)


class ConfigErrors(ConfigError):
    """Several errors of one file, reported together: its message is one line per error."""

    def __init__(self, errors: Sequence[ConfigError]):
        self.errors = list(errors)
        first = self.errors[0]
        self.source, self.path, self.value, self.expected = first.source, "", _MISSING, None
        self.message = "\n".join(str(e) for e in self.errors)
        ValueError.__init__(self, self.message)


class ErrorLog:
    """Collects ConfigErrors so a file's faults are all reported at once, not one per run.

    A reader wraps each independent part (a section, a list item, a cost term) in
    :meth:`collect` or :meth:`call`; :meth:`raise_if_any` raises what was found: the single
    :class:`ConfigError`, or :class:`ConfigErrors` for several.
    """

    def __init__(self) -> None:
        self.errors: list[ConfigError] = []

    def add(self, exc: ConfigError) -> None:
        self.errors.extend(exc.errors if isinstance(exc, ConfigErrors) else [exc])

    @contextmanager
    def collect(self):
        """Run a block; a ConfigError it raises is recorded and the block is abandoned."""
        try:
            yield
        except ConfigError as exc:
            self.add(exc)

    def call(self, fn: Callable[..., Any], *args: Any, default: Any = None, **kwargs: Any) -> Any:
        """``fn(*args, **kwargs)``, or ``default`` with the ConfigError recorded."""
        try:
            return fn(*args, **kwargs)
        except ConfigError as exc:
            self.add(exc)
            return default

    def raise_if_any(self) -> None:
        if len(self.errors) == 1:
            raise self.errors[0]
        if self.errors:
            raise ConfigErrors(self.errors)


_WARNED: set[str] = set()


def deprecated(old: str, instead: str) -> None:
    """Warn once per process that the spelling ``old`` (a key, a command-line option) is
    deprecated, saying what to write ``instead``; CHANGELOG.md lists when it goes."""
    if old in _WARNED:
        return
    _WARNED.add(old)
    # attributed to the project, not to a line of its code: the user's spelling is at fault
    warnings.warn_explicit(
        f"{old} is deprecated and will be removed: {instead}", FutureWarning, "m3p2i", 0
    )


def load_yaml(path: str | Path) -> dict:
    """Read a YAML mapping with the safe loader; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(str(path), "", "file not found")
    try:
        with path.open() as f:
            data = yaml.safe_load(f)
    except yaml.YAMLError as exc:
        raise ConfigError(str(path), "", f"not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(
            str(path), "", "top level must be a mapping", type(data).__name__, "key: value pairs"
        )
    return data


class Section:
    """A mapping at a key path of a config file, read strictly.

    Keys are consumed with :meth:`req` / :meth:`opt` / :meth:`section`; :meth:`done` then fails on
    any key that was not consumed. Values keep YAML's types; numbers accept ints where floats are
    expected.
    """

    def __init__(self, data: Any, source: str, path: str = ""):
        if not isinstance(data, dict):
            raise ConfigError(
                source, path or "(top level)", "must be a mapping", data, "key: value pairs"
            )
        self.data, self.source, self.path = data, source, path
        self._seen: set[str] = set()

    def key_path(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def error(
        self, key: str | int, message: str, value: Any = _MISSING, expected: str | None = None
    ) -> ConfigError:
        return ConfigError(self.source, self.key_path(key), message, value, expected)

    def has(self, key: str) -> bool:
        return key in self.data

    def req(
        self, key: str, kind: Callable[[Any], Any] | type = object, expected: str | None = None
    ):
        """A required value, checked by ``kind`` (a type, or a converter raising ValueError)."""
        if key not in self.data:
            raise ConfigError(
                self.source, self.key_path(key), "missing required key", expected=expected
            )
        return self._convert(key, self.data[key], kind, expected)

    def opt(
        self,
        key: str,
        default: Any,
        kind: Callable[[Any], Any] | type = object,
        expected: str | None = None,
    ):
        """An optional value; ``default`` when absent."""
        if key not in self.data:
            self._seen.add(key)
            return default
        return self._convert(key, self.data[key], kind, expected)

    def renamed(self, old: str, new: str) -> str:
        """The key to read for ``new``: ``old`` when only the old spelling is given (it warns
        once, naming ``new``); both given: an error."""
        if old not in self.data:
            return new
        if new in self.data:
            raise self.error(old, f"both {new} and {old} (its old name) given", expected=new)
        deprecated(f"{self.key_path(old)} (in {self.source})", f"write {self.key_path(new)}")
        return old

    def section(self, key: str, required: bool = True) -> Section:
        """A nested mapping (an empty one when optional and absent)."""
        if key not in self.data:
            if required:
                raise ConfigError(
                    self.source,
                    self.key_path(key),
                    "missing required section",
                    expected="a mapping",
                )
            self._seen.add(key)
            return Section({}, self.source, self.key_path(key))
        self._seen.add(key)
        return Section(self.data[key], self.source, self.key_path(key))

    def items(self, key: str, required: bool = False) -> list[Section]:
        """A list of mappings, each as a Section with an indexed path (``objects[2]``)."""
        raw = self.req(key, list, "a list") if required else self.opt(key, [], list, "a list")
        base = self.key_path(key)
        return [Section(item, self.source, f"{base}[{i}]") for i, item in enumerate(raw)]

    def done(self) -> None:
        """Fail on keys that no reader consumed (typos, misplaced keys)."""
        unknown = sorted(set(self.data) - self._seen, key=str)
        if unknown:
            allowed = ", ".join(sorted(self._seen)) or "(none)"
            raise ConfigError(
                self.source,
                self.key_path(str(unknown[0])),
                "unknown key",
                expected=f"one of: {allowed}",
            )

    def _convert(self, key: str, value: Any, kind, expected: str | None):
        self._seen.add(key)
        if isinstance(kind, type):
            if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
                return self._convert(key, value, number, expected)
            if kind in (int, float) and isinstance(value, bool):
                raise self.error(key, "wrong type", value, expected or kind.__name__)
            if kind is not object and not isinstance(value, kind):
                raise self.error(key, "wrong type", value, expected or kind.__name__)
            return value
        try:
            return kind(value)
        except (ValueError, TypeError) as exc:
            raise self.error(key, str(exc) or "invalid value", value, expected) from None


# Converters for Section.req/opt: each raises ValueError with the reason.


def number(value: Any) -> float:
    """A finite number: YAML's ``.inf`` and ``.nan`` are refused (``nan < 0`` is false, so a NaN
    would pass every range check after this one; no key of a file means "unbounded" by inf)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("wrong type")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range
        raise ValueError("must be a finite number") from None
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


def positive(value: Any) -> float:
    v = number(value)
    if not v > 0:
        raise ValueError("must be > 0")
    return v


def non_negative(value: Any) -> float:
    v = number(value)
    if v < 0:
        raise ValueError("must be >= 0")
    return v


def flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError("wrong type")
    return value


def positive_int(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ValueError("must be a positive integer")
    return value


def vector(n: int | None = None) -> Callable[[Any], tuple[float, ...]]:
    """Converter for a list of numbers, of length ``n`` when given."""

    def convert(value: Any) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)):
            raise ValueError("wrong type")
        if n is not None and len(value) != n:
            raise ValueError(f"needs {n} numbers")
        return tuple(number(v) for v in value)

    return convert


def one_of(choices: Iterable[str]) -> Callable[[Any], str]:
    """Converter for a string from a fixed set."""
    options = sorted(choices)

    def convert(value: Any) -> str:
        if value not in options:
            raise ValueError(f"must be one of: {', '.join(options)}")
        return value

    return convert


def string_list(value: Any) -> tuple[str, ...]:
    if isinstance(value, str):
        return (value,)
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ValueError("wrong type")
    return tuple(value)
