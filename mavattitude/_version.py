"""The package's version, in a module of its own so that any module can say it (a JSON file's
``written_by``, bench's record) without importing the package's ``__init__``, the Python API
at the top of the import graph. Keep it equal to pyproject.toml's ``version``."""

__version__ = "0.1.0"
