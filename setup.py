"""The compiled part of the robot's decision (runtime/_kernel.c; see runtime/kernel.py).

Everything else about the package is in pyproject.toml. The extension is optional:
without a C compiler the install goes on and the robots decide in Python (the same
numbers, slower).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "runtime._kernel",
            ["runtime/_kernel.c"],
            # the Python reference's IEEE operations, one by one: no fused multiply-add
            extra_compile_args=["-O2", "-ffp-contract=off", "-fno-fast-math"],
            optional=True,
        )
    ]
)
