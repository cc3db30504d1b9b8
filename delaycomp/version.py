"""The version of delaycomp, a leaf that imports nothing: the modules below the face read
it here, never through the package's face (``delaycomp/__init__.py``, which hands on the
API)."""

__version__ = "0.1.0"
