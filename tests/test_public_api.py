"""Public API discipline (httpx's test_exported_members): ``__all__`` lists exactly the public names
and the stable entry points of docs/architecture.md exist with their documented signatures."""

from __future__ import annotations

import importlib
import inspect

import pytest

import cnctwin

MODULES = [
    "cnctwin",
    "cnctwin.signals",
    "cnctwin.recording",
    "cnctwin.exceptions",
    "cnctwin.iotools",
    "cnctwin.usecases",
]


@pytest.mark.parametrize("name", MODULES)
def test_all_names_exist_and_are_public(name: str) -> None:
    mod = importlib.import_module(name)
    exported = mod.__all__
    assert len(exported) == len(set(exported)), "duplicates in __all__"
    for item in exported:
        assert hasattr(mod, item), f"{name}.__all__ names missing {item!r}"


def test_top_level_all_is_the_curated_public_surface() -> None:
    public = {
        n for n in dir(cnctwin)
        if not n.startswith("_") and n != "annotations"  # the __future__ feature object
        and not inspect.ismodule(getattr(cnctwin, n))
    }
    assert public <= set(cnctwin.__all__)


def test_stable_entry_points() -> None:
    # shared/reference/architecture.md: names and meanings that other tools rely on.
    from cnctwin.spindle import SpindleModel, calibrate, fit_friction

    assert callable(cnctwin.read_recording)
    sig = inspect.signature(fit_friction)
    assert list(sig.parameters)[:4] == ["speed_rpm", "current_a", "lo_rpm", "hi_rpm"]
    assert list(inspect.signature(calibrate).parameters)[:4] == [
        "fit", "current_a", "torque_nm", "speed_rpm"]
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    assert model.j_kgm2 == 0.0
    from cnctwin.sim import scenarios, simulate  # noqa: F401
