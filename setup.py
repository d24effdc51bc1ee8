"""The wheel's packages: every package under ``drake_cfvol/`` as found on
disk (never a hand list), plus the repository's top-level ``models/`` and
``diagrams/`` folders, which pyproject.toml's ``package-dir`` maps to
``drake_cfvol.models`` and ``drake_cfvol.diagrams``. Everything else is in
pyproject.toml."""

from setuptools import find_packages, setup

#: Top-level data folders shipped inside the package (see pyproject.toml's
#: ``[tool.setuptools.package-dir]``).
DATA_PACKAGES = ["drake_cfvol.models", "drake_cfvol.diagrams"]

setup(packages=find_packages(include=["drake_cfvol", "drake_cfvol.*"]) + DATA_PACKAGES)
