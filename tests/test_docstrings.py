"""numpydoc validation of the public API (issue 16, point 6).

The public API is every name in the ``__all__`` of a module whose path has no leading
underscore (``cnctwin.usecases.holes``, not ``cnctwin.iotools._c4a_state``): what the
packages export and what their modules offer. Every such function documents each parameter
with a description (PR01, PR02, PR07, PR10) and has a Returns section where it returns
something (RT01); every exported class has a docstring (GL08). Checked with numpydoc's own
validator, as pandas and scipy do.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import numpydoc.validate as numpydoc_validate

import cnctwin

FUNCTION_CHECKS = {"GL08", "PR01", "PR02", "PR07", "PR10", "RT01"}


def _public_api() -> tuple[list[str], list[str]]:
    modules = ["cnctwin"] + [
        m.name for m in pkgutil.walk_packages(cnctwin.__path__, "cnctwin.")
        if not any(part.startswith("_") for part in m.name.split(".")[1:])]
    functions: set[str] = set()
    classes: set[str] = set()
    for name in modules:
        mod = importlib.import_module(name)
        for attr in getattr(mod, "__all__", []):
            obj = getattr(mod, attr)
            if inspect.isfunction(obj):
                functions.add(f"{obj.__module__}.{obj.__qualname__}")
            elif inspect.isclass(obj) and obj.__module__.startswith("cnctwin"):
                classes.add(f"{obj.__module__}.{obj.__qualname__}")
    return sorted(functions), sorted(classes)


FUNCTIONS, CLASSES = _public_api()


def test_the_public_api_is_found() -> None:
    assert len(FUNCTIONS) > 300 and len(CLASSES) > 100


def test_exported_functions_document_parameters_and_returns() -> None:
    bad = {}
    for name in FUNCTIONS:
        errors = [f"{code}: {msg}" for code, msg in numpydoc_validate.validate(name)["errors"]
                  if code in FUNCTION_CHECKS]
        if errors:
            bad[name] = errors
    assert bad == {}


def test_exported_classes_have_docstrings() -> None:
    bad = [name for name in CLASSES
           if any(code == "GL08" for code, _ in numpydoc_validate.validate(name)["errors"])]
    assert bad == []
