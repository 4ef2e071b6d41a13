"""Build the C extensions (the model's generated dynamics, the compiled control step, the
truth plant's step kernel); all other metadata lives in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "companion.model._mcg",
            sources=["companion/model/_mcg.c"],
            extra_compile_args=["-O2"],
        ),
        # The step must reproduce the Python reference operation for operation: no fused
        # multiply-add (aarch64 compilers contract a * b + c by default).
        Extension(
            "companion.control._step",
            sources=["companion/control/_step.c"],
            depends=["companion/model/_mcg.c"],
            extra_compile_args=["-O2", "-ffp-contract=off"],
        ),
        # The truth plant's per-step arithmetic; no contraction into fused multiply-adds, so
        # that it computes what the Python it mirrors computes.
        Extension(
            "sitl.physics._kernel",
            sources=["sitl/physics/_kernel.c"],
            extra_compile_args=["-O2", "-ffp-contract=off"],
        ),
        # The XM430 servo model's per-step physics, operation for operation as its Python.
        Extension(
            "sitl.servo._xm430",
            sources=["sitl/servo/_xm430.c"],
            extra_compile_args=["-O2", "-ffp-contract=off"],
        ),
    ]
)
