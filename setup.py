"""The compiled decision (runtime/core/*.py) and contact model (trainer/world/contacts.py).

Everything else about the package is in pyproject.toml. Each module is plain Python in
Cython's pure-Python mode, compiled at install; the build is optional: without a C compiler
the install goes on and the same source runs as Python (the same numbers, slower).
"""

from pathlib import Path

from setuptools import Extension, setup

# the decision's math (runtime/core) and the training world's contact model
COMPILED = [
    *sorted(p for p in Path("runtime/core").glob("*.py") if p.name != "__init__.py"),
    Path("trainer/world/contacts.py"),
]


def extensions() -> list[Extension]:
    try:
        from Cython.Build import cythonize
    except ImportError:  # no Cython: the modules run as Python
        return []
    exts = [
        Extension(
            ".".join(p.with_suffix("").parts),
            [str(p)],
            # the Python source's IEEE operations, one by one: no fused multiply-add
            extra_compile_args=["-O2", "-ffp-contract=off", "-fno-fast-math"],
            optional=True,
        )
        for p in COMPILED
    ]
    # the C that Cython writes goes to build/, beside nothing of the source tree
    return list(cythonize(exts, language_level=3, quiet=True, build_dir="build/cython"))


setup(ext_modules=extensions())
