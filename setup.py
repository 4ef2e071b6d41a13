"""Build the C extension of the model's generated dynamics and the compiled twins of
pure-Python modules (the control step among them); all other metadata lives in
pyproject.toml.

A compiled twin is a module's own Python source compiled by Cython (pure-Python mode) into
``_<name>`` beside it: the source is copied to ``build/cython/<package>/_<name>.py`` with
its SHA-256 appended as ``SOURCE_SHA256``, so that :mod:`companion.compiled` loads the twin
only while the source is the one it was built from.
"""

import hashlib
import os
from pathlib import Path

from Cython.Build import cythonize
from setuptools import Extension, setup

ROOT = Path(__file__).resolve().parent
TWINS = (
    "companion.control.control_step",
    "sitl.vehicle_step",
)
"""Modules written once in Python and also built compiled."""


def twin_source(module: str) -> str:
    """``build/cython/<package>/_<name>.py``: the module's source and its SHA-256 (the
    path relative to this directory)."""
    source = ROOT.joinpath(*module.split(".")).with_suffix(".py")
    text = source.read_bytes()
    digest = hashlib.sha256(text).hexdigest()
    copy = ROOT.joinpath("build", "cython", *module.split(".")[:-1], f"_{source.stem}.py")
    copy.parent.mkdir(parents=True, exist_ok=True)
    body = text + f'\nSOURCE_SHA256 = "{digest}"\n'.encode()
    if not copy.exists() or copy.read_bytes() != body:
        copy.write_bytes(body)
    return str(copy.relative_to(ROOT))


def twin(module: str) -> Extension:
    package, _, name = module.rpartition(".")
    # No contraction into fused multiply-adds: the twin computes what the Python computes.
    return Extension(
        f"{package}._{name}",
        sources=[twin_source(module)],
        extra_compile_args=["-O2", "-ffp-contract=off"],
    )


setup(
    # The extensions compile side by side, one per core (the twins' generated C is large).
    options={"build_ext": {"parallel": os.cpu_count() or 1}},
    ext_modules=[
        Extension(
            "companion.model._mcg",
            sources=["companion/model/_mcg.c"],
            extra_compile_args=["-O2"],
        ),
        *cythonize(
            [twin(module) for module in TWINS],
            compiler_directives={"language_level": 3},
            # The twins' cimports (companion/model/mcg_eval.pxd) are found from the root.
            include_path=[str(ROOT)],
            quiet=True,
        ),
    ],
)
