"""Each concept package of companion lists its public names in its __init__: every one
resolves, to the object its home module defines, without an import cycle."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

PACKAGES = ("companion.mission", "companion.control", "companion.estimation", "companion.cli")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_resolves_to_its_home(package: str) -> None:
    module = importlib.import_module(package)
    assert module.__all__
    homes = getattr(module, "_HOME", {})
    for name in module.__all__:
        value = getattr(module, name)
        if name in homes:
            assert value is getattr(importlib.import_module(homes[name]), name)
    with pytest.raises(AttributeError, match="has no attribute"):
        _ = module.NoSuchName


@pytest.mark.parametrize("package", PACKAGES)
def test_a_fresh_interpreter_imports_each_package_and_its_names_first(package: str) -> None:
    names = ", ".join(importlib.import_module(package).__all__)
    done = subprocess.run(
        [sys.executable, "-c", f"from {package} import {names}"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
