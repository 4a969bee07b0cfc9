"""The package version, in a module of its own: code anywhere in floaff_zoo can read it without
importing the package's lazy ``predict`` hook (``floaff_zoo/__init__.py``)."""

__version__ = "0.1.0"
