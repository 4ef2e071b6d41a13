"""Compiled twins (companion.compiled): each module setup.py compiles is built from its
source as it is now, and a twin built from another source is never run."""

from __future__ import annotations

import ast
import importlib
import logging
from pathlib import Path

import pytest

from companion import compiled

ROOT = Path(__file__).resolve().parent.parent


def twins() -> list[str]:
    """setup.py's TWINS, read without running setup.py."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "TWINS":
            return list(ast.literal_eval(node.value))
    raise AssertionError("setup.py lists no TWINS")


@pytest.mark.parametrize("name", twins())
def test_every_twin_is_built_from_its_source_as_it_is(name: str) -> None:
    module = importlib.import_module(name)
    assert compiled.twin_reason(module) is None, compiled.twin_reason(module)
    fast = compiled.twin(module)
    assert fast is not module and fast.__name__ == compiled.twin_name(name)
    assert Path(fast.__file__).suffix in (".so", ".pyd")


def test_a_stale_or_missing_twin_runs_the_python_and_says_why(monkeypatch, caplog) -> None:
    module = importlib.import_module(twins()[0])
    fast = compiled.twin(module)
    monkeypatch.setattr(fast, "SOURCE_SHA256", "0" * 64)
    monkeypatch.setattr(compiled, "_warned", set())
    with caplog.at_level(logging.WARNING, logger=compiled.__name__):
        assert compiled.twin(module) is module
        assert compiled.twin(module) is module
    assert [r.getMessage() for r in caplog.records] == [
        f"{fast.__name__} was built from another {Path(module.__file__).name} "
        "(rebuild: `python setup.py build_ext --inplace`): running its Python source"
    ]
    assert compiled.twin(module, compiled=False) is module
    missing = importlib.import_module("companion.frames")
    assert "companion._frames is not built" in compiled.twin_reason(missing)
