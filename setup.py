"""Build the generated dynamics extension; all other metadata lives in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "companion.model._mcg",
            sources=["companion/model/_mcg.c"],
            extra_compile_args=["-O2"],
        )
    ]
)
