"""The user's cost terms: Python modules outside the package that register terms with the
package's decorator (``@register("name")`` of :mod:`planner_client.costs`), imported by the
planner (docs/cost_terms.md, "Your own cost terms").

Only the operator chooses what is imported, on the planner's machine: the ``plugins:`` list of
the scenario file the planner reads from its own disk, and ``m3p2i-planner --plugins``. Nothing
received over the wire names a module: the handshake carries the scenario's name and hash, never
its text, and a Ray node refuses a scenario sent to it that names plugins
(``m3p2i.bench_ray``).

A plugin is named as a file (``my_terms.py``, or ``my_terms``: ``my_terms.py`` or the package
``my_terms/`` in the scenario's folder) or, when no such file is there, as a module on the
Python path (``lab.costs``). Each file is imported once per process, whoever names it.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from shared.config import ConfigError, ErrorLog

_BY_FILE: dict[Path, ModuleType] = {}  # a plugin file -> its module, imported once
_PACKAGE = str(Path(__file__).resolve().parent.parent)  # the m3p2i source tree


def plugin_file(ref: str, folder: Path) -> Path | None:
    """The file that ``ref`` names in ``folder`` (a ``.py`` file, or a package's
    ``__init__.py``), or None when ``ref`` is to be imported by module name."""
    candidates = [folder / ref] if ref.endswith(".py") else [folder / f"{ref}.py"]
    if not ref.endswith(".py"):
        candidates.append(folder / ref / "__init__.py")
    return next((p.resolve() for p in candidates if p.is_file()), None)


def import_plugins(
    refs: Sequence[str], folder: Path, source: str, key: str = "plugins"
) -> list[ModuleType]:
    """Import each plugin of ``refs`` (files relative to ``folder``, else module names); every
    failure is reported together, each as a :class:`ConfigError` naming ``source``, ``key[i]``,
    the plugin and what went wrong: no such module, or the exception its import raised (a term
    registered twice among them) with the line of the plugin it came from."""
    errors = ErrorLog()
    modules = [
        errors.call(import_plugin, ref, folder, source, f"{key}[{i}]") for i, ref in enumerate(refs)
    ]
    errors.raise_if_any()
    return modules


def import_plugin(ref: str, folder: Path, source: str, key: str) -> ModuleType:
    """One plugin (see :func:`import_plugins`)."""
    if not isinstance(ref, str) or not ref.strip():
        raise ConfigError(source, key, "not a module name", ref, "a module or a .py file")
    path = plugin_file(ref, folder)
    if path is None and (ref.endswith(".py") or "/" in ref):
        raise ConfigError(
            source, key, "no such plugin file", ref, f"a Python file; looked in {folder}"
        )
    try:
        return _import_file(path) if path is not None else _import_module(ref, folder, source, key)
    except ConfigError:
        raise
    except BaseException as exc:  # the plugin's own code failed: say where, not only what
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise ConfigError(
            source, key, f"importing the plugin failed: {exception_summary(exc)}", ref
        ) from None


def _import_module(ref: str, folder: Path, source: str, key: str) -> ModuleType:
    try:
        return importlib.import_module(ref)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (ref == exc.name or ref.startswith(f"{exc.name}.")):
            raise ConfigError(
                source,
                key,
                "no such plugin module",
                ref,
                f"{ref}.py or {ref}/ in {folder}, or a module importable by this Python",
            ) from None
        raise


def _import_file(path: Path) -> ModuleType:
    """Import a plugin file under a name of its own (its stem and a hash of its path, so that
    two files of the same name in different folders do not collide)."""
    if path in _BY_FILE:
        return _BY_FILE[path]
    stem = path.parent.name if path.name == "__init__.py" else path.stem
    name = f"m3p2i_plugin_{stem}_{hashlib.sha1(str(path).encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(
        name,
        path,
        submodule_search_locations=[str(path.parent)] if path.name == "__init__.py" else None,
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look a module up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    _BY_FILE[path] = module
    return module


def origin(cls: type) -> str:
    """Where a class comes from, for messages: ``Name in plugin /path/file.py`` for one of a
    plugin file (its module's name is made up by :func:`_import_file`: the file says more),
    ``Name in module.name`` otherwise."""
    module = sys.modules.get(cls.__module__)
    if cls.__module__.startswith("m3p2i_plugin_") and getattr(module, "__file__", None):
        return f"{cls.__qualname__} in plugin {module.__file__}"
    return f"{cls.__qualname__} in {cls.__module__}"


def exception_summary(exc: BaseException) -> str:
    """``Type: message (at FILE:LINE in FUNCTION: code)``: the exception and the last frame of
    its traceback in the user's code (outside m3p2i and the import machinery), where the
    plugin failed; the last frame of all when none is."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if "importlib" not in f.filename]
    users = [f for f in frames if not f.filename.startswith(_PACKAGE)]
    text = f"{type(exc).__name__}: {exc}"
    if users or frames:
        f = (users or frames)[-1]
        text += f" (at {f.filename}:{f.lineno} in {f.name}: {(f.line or '').strip()})"
    return text
